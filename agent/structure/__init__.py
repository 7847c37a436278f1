"""Real structures as triangle meshes: loading, landmark sampling, occlusion and clearance,
and (``model``) the planner's view of one structure: occlusion masks refreshed by distance,
section-4.3 obstacle rows and safe steps, as plain arrays for :mod:`agent.core`.

Every position is in metres in the world frame (ENU), like :mod:`agent.core`. Landmarks are
returned as row arrays ``(q, u)`` of shape (m, 3), as in :mod:`agent.core.landmarks`.
"""
