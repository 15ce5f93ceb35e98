"""Validation on held-out logs: does a calibration make dead reckoning better?
"""
