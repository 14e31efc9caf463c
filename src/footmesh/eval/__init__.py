"""Evaluation on held-out synthetic test splits, printing the thesis' tables with its numbers beside ours."""
