"""In-process simulators (chapter 5 kinematic simulation)."""
