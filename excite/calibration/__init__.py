"""Batch calibration: the pipeline from segments to a documented result, its starts, solver,
noise model, model choice and fit tests, and export to ROS 2.
"""
