"""Generic statistics: chi-square helpers, serial correlation, estimator consistency (NEES),
pooling groups' estimates (meta-analysis).
"""
