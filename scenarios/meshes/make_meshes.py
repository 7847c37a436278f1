"""Write the example structure meshes used by the shipped scenarios (run once, from the repo
root: ``.venv/bin/python scenarios/meshes/make_meshes.py``). The meshes are trimesh
primitives built by :mod:`agent.structure.examples` with their default sizes [m]: an
L-shaped building, a bridge (two piers and a deck) and a tower, each standing on z = 0."""

from __future__ import annotations

from pathlib import Path

from agent.structure.examples import write_examples

if __name__ == "__main__":
    for path in write_examples(Path(__file__).resolve().parent):
        print(path)
