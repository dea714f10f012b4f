"""
Infrastructure that every layer may import: atomic file writes and a progress bar.

Nothing here knows about geometry, ROS or the pipeline, so the arrows of the package's layers
all point down to it.
"""
