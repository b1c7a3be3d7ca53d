"""The README's Python example runs as written (on a tiny model)."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_python_api_example_runs(tiny_model, tmp_path, monkeypatch):
    (block,) = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    monkeypatch.chdir(tmp_path)
    exec(compile(block.replace('"towerruins.onnx"', repr(str(tiny_model))), "README.md", "exec"), {})
    assert sorted(p.name for p in tmp_path.glob("tower_*.ply")) == sorted(f"tower_{s}.ply" for s in range(3))
