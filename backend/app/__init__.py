"""The application edge: everything that touches files, processes, exit codes and the environment.

- :mod:`.folder`: one fit from photo files to a results folder (the fit command's job);
- :mod:`.report`: the report image of a fit;
- :mod:`.batch`: every pair of a folder fitted on Ray;
- :mod:`.cli`: ``python -m backend``'s commands.

The library below it (core, image, model, texture, init, fit) takes and returns values.
"""
