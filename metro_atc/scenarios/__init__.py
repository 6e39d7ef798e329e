"""Embedded scenario files (``*.yaml``) and their schema description (``SCHEMA.md``)."""
