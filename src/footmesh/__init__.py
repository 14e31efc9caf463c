"""footmesh: 3D mesh, pose, measurements and shoe sizes of a foot from one photo."""

__version__ = "0.1.0"
