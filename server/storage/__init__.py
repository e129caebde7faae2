"""Persistence: SQL models and repositories, the session state store, array codecs."""
