"""Real structures as triangle meshes: loading, landmark sampling, occlusion and clearance.

Every position is in metres in the world frame (ENU), like :mod:`agent.core`. Landmarks are
returned as row arrays ``(q, u)`` of shape (m, 3), as in :mod:`agent.core.landmarks`.
"""
