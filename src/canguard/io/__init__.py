"""Frames in and out of the process: python-can buses, log readers and writers, frame types."""
