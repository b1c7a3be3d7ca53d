"""Models shipped with sinshape: every NAME.onnx in this folder, with its
card NAME.md beside it. It imports only sinshape.core's errors: finding a
model loads nothing."""

from importlib import resources
from pathlib import Path

from sinshape.core.errors import InputError

DEFAULT = "towerruins"  # what `sinrun sample` uses when no model is named


def available() -> dict:
    """Shipped model names -> paths."""
    folder = resources.files(__name__)
    return {Path(p.name).stem: Path(str(p)) for p in folder.iterdir() if p.name.endswith(".onnx")}


def find(name_or_path: str | None) -> Path:
    """A model file: an existing path, or the name of a shipped model (None: the default)."""
    shipped = available()
    if name_or_path is None:
        if DEFAULT not in shipped:
            raise InputError("no model given and no default model is installed; name a .onnx file")
        return shipped[DEFAULT]
    path = Path(name_or_path)
    if path.is_dir():
        raise InputError(f"{path}: a directory, not a model file")
    if path.is_file() or path.suffix.lower() == ".onnx":
        return path  # load() reports a missing file
    if name_or_path in shipped:
        return shipped[name_or_path]
    names = ", ".join(sorted(shipped)) or "none installed"
    raise InputError(f"{name_or_path}: neither a model file nor a shipped model ({names})")


def own_file(name_or_path: str | None, output) -> Path:
    """Where a change to a model goes: `output`, or the model's own file,
    unless it is a shipped one (the installed package is not the user's to change)."""
    if output is not None:
        return Path(output)
    path = find(name_or_path)
    if path in available().values():
        raise InputError(f"{path.stem} is a shipped model: write the change to a file of your own with `output`",
                         "output")
    return path
