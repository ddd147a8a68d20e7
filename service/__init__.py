"""The shsas HTTP service (FastAPI): uploads, jobs, artifacts, API keys.

Kept import-light: ``python -m service.validate_child`` imports this package in a
memory-limited child. The app lives in :mod:`service.app` (``create_app``).
"""
