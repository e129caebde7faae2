"""Use-cases: load state, run the core, persist and publish. Services own transactions."""
