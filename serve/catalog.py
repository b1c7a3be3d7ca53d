"""The models a server or a static site serves: which names, loaded and
checked once, and what a client is told about each. `sinrun serve` (app.py)
and `sinrun export-web` (site.py) both decide here, so a model gets the same
name in both. Needs no FastAPI."""

from pathlib import Path

from sinshape import models as shipped
from sinshape.core.errors import InputError
from sinshape.runtime import load


def load_models(names, threads: int | None = None) -> dict:
    """Shipped model names or .onnx paths -> {name: loaded model}; none: every shipped model.
    A shipped model is named by its name, a file by its stem; two of one name are refused."""
    paths = {}
    for item in names or sorted(shipped.available()):
        path = shipped.find(item)
        name = item if item in shipped.available() and not Path(item).is_file() else path.stem
        if name in paths:
            raise InputError(f"two models are called {name!r}; rename one file")
        paths[name] = path
    if not paths:
        raise InputError("no model given and no shipped model is installed; name a .onnx file")
    return {name: load.load_model(path, threads=threads) for name, path in paths.items()}


def entry(name: str, model) -> dict:
    """A model in a list of them (the server's /api/models, the site's models.json)."""
    sizes = model.manifest.sizes
    return {"name": name, "size": list(sizes[-1]), "levels": len(sizes), "up": model.manifest.up,
            "arrange": model.manifest.arrange}


def summary(name: str, model) -> dict:
    """What a client needs to know about a model: its levels, sizes, training input and config."""
    m = model.manifest.raw
    training = m.get("training", {})
    return {
        "name": name,
        "file": model.path.name,
        "levels": len(m["levels"]),
        "size": list(model.manifest.sizes[-1]),
        "sizes": [list(s) for s in model.manifest.sizes],
        "noise_amps": model.manifest.noise_amps,
        "training_input": m.get("source", {}),
        "training": {key: training[key] for key in ("seconds", "iterations_per_level") if key in training},
        "config": m.get("config", {}),
        "frame": m["frame"],
        "up": model.manifest.up,
        "arrange": model.manifest.arrange,
        "object_scale": model.manifest.object_scale,
        "format_version": m["format_version"],
    }
