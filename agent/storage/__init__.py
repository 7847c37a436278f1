"""Durable state: the agent's CRC-framed, fsynced journal (:mod:`agent.storage.journal`)."""
