"""Imported by the web server's forkserver (``WebSettings.preload``): the pipeline's foot model and networks loaded
once there, so that every measurement forked from it has them in memory (copy-on-write) instead of loading them
itself, and a request costs what a measurement in a warm process costs. Only loading happens here, no inference:
the forkserver starts no compute threads that a fork would leave behind."""

from footmesh.pipeline import warm_up

warm_up()
