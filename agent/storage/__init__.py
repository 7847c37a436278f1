"""Durable state and file formats: the agent's CRC-framed, fsynced journal
(:mod:`agent.storage.journal`) and the MCAP recording's channels and colours
(:mod:`agent.storage.recording`), read by the recorder and by replay alike."""
