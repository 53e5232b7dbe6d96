"""The one error of photo input: :class:`PhotoError`.

A ``ValueError`` whose message names the file (or the pair, ``reflection / transmission``) and the
problem, so that the command line can print it as is and exit with the input-error status.
"""
from __future__ import annotations


class PhotoError(ValueError):
    """A photo cannot be used; the message names the file and the problem."""
