"""The agent process: pose sources, clocks, the agent runtime (trade client/server,
membership, completion detection) and its command-line entry points."""
