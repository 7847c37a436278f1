"""The ``viscover`` subcommands: each module parses its options and calls one function of a
lower layer (:mod:`agent.runtime`, :mod:`agent.sim`); :mod:`agent.commands.kit` is what they
share. The entry point that registers them (and the ground station's) is :mod:`agent.cli`."""
