"""The README's code runs as written."""

import re
from pathlib import Path

README = Path(__file__).resolve().parent.parent / "README.md"


def test_readme_tour_runs(tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}  # one session, as a reader runs the blocks in order
    for code in blocks:
        exec(compile(code, str(README), "exec"), namespace)
    assert (tmp_path / "pose.png").is_file()
