"""Importers: turn robot descriptions written for other frameworks into hild configs (``hild import ...``)."""
