"""Logs in, logs out: segment files, time-series CSVs, ROS bags, clock synchronisation,
segmentation into motion segments, and synthetic logs.
"""
