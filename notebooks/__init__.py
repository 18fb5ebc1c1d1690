"""The validation notebooks: ``python -m notebooks.build`` writes and runs them."""
