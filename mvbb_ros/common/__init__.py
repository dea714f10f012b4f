"""
Infrastructure that every layer may import: atomic file writes, a progress bar, worker threads.

Nothing here knows about geometry, ROS or the pipeline, so the arrows of the package's layers
all point down to it.
"""
