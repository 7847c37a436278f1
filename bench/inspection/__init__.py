"""The inspection benchmark's parts: scenes (structures, random starts), the centralised
offline plan it is compared with, and the independent re-check of every capture."""
