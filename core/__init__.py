"""The floor everything else stands on: errors, the memory budget, the model
format (its manifest and seal, and the noise a seed stands for) and atomic
files.

Light (numpy at most) and self-contained: it imports nothing from the rest of
sinshape, and prep, runtime, trainer, serve and cli all import it. The
import rules are tested (tests/test_imports.py) against the table in
docs/ARCHITECTURE.md.
"""
