"""``python -m devtools``: the developer commands."""
