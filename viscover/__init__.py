"""viscover's Python API for lab scripts: :mod:`viscover.api` (launch or attach to a mission,
watch it, land or stop its drones, read its results; rehearse one in memory). Documented in
docs/api.md. It sits above every layer of :mod:`agent` (it imports them, nothing imports it)
and needs nothing of :mod:`groundstation` (``viscover launch --flight`` runs the ground station
as a process)."""
