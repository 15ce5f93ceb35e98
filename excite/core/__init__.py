"""The math every layer shares: SE(2) poses, the arc of one segment and its sinc family,
the segment models, the information measures, symmetric band matrices and the arena's
geometry (numpy/scipy only).
"""
