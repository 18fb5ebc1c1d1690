"""The render pipeline behind ``render.py``: variant choice, jobs, outputs."""
