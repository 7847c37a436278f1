"""Files users write, validated by msgspec with one-line errors naming file, field and fix:
scenarios (:mod:`agent.config.scenario`) and flight settings (:mod:`agent.config.flight`)."""
