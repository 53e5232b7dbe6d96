"""Developer tools, outside the shipped extension: benchmarks and their results ledger, the
photo-like generator and its phone model, the initialisation network's dataset and training.

``python -m devtools <command>`` from the repository root (``python -m devtools --help``). They
import the backend; the backend never imports them (tests/test_layers.py).
"""
