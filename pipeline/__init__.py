"""firefly3d science core: from stereo 360-degree videos to 3D firefly flash trajectories.

This package never imports web, database or task-queue code; the service in
``services/`` wraps its stage functions.
"""

__version__ = "0.1.0"
