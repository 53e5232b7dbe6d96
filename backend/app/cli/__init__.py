"""``python -m backend``: the commands a user and the Blender add-on call."""
