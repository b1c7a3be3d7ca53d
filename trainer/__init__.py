"""The sinshape trainer: fit the multi-scale tri-plane GAN to one example
shape and export it as one .onnx file (needs the train extra, PyTorch).

    from sinshape.trainer import train
    from sinshape.trainer.config import make_config

    train.train("mymesh.obj", "mymesh.onnx", make_config("default"))

Modules: config (the frozen settings and presets), networks, device,
steps (the Trainer: a run's state and one iteration), train (the run, a
loop over levels), schedule (a time budget turned into iterations per
level), rewind (going back when a level diverges), checkpoint (saving and
resuming), memory (what a level needs), export (the .onnx file). The input
becomes voxel levels in sinshape.prep, which evaluation shares.

It imports torch, onnx and numpy, sinshape.prep (the voxel levels, with
their readers) and sinshape.core (the errors, the manifest format, the
noise, atomic files: the contract it shares with the runtime). Never the
runtime, the CLI or serve (docs/ARCHITECTURE.md's import rules, tested).
The method is described in docs/METHOD.md, the file it writes in
docs/FORMAT.md.
"""
