"""README.md keeps its promises.

Fast checks, read from the README's own text: every `lensim ...` command it shows is a
command of the CLI (the one `lensim --help` lists) and takes every option it is shown
with; every module in the stage table and every `lensim.x.y` name imports or resolves;
the Python examples import only names that exist and call the entry point of every stage;
every repository file or link it names exists. The slow test runs the Python examples as
written (the second one trains and runs the quick demo); they read `photo.png` and the
folder `photos/`, which the test fills with built-in sample photos."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import math
import re
import shlex
from pathlib import Path
from typing import Any

import pytest
import typer

from lensim.assets.images import available_sample_images, read_sample_image
from lensim.cli import app
from lensim.images import write_image

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
TEXT = README.read_text(encoding="utf-8")
# top-level repository folders whose paths the README may name as existing files
REPO_FOLDERS = ("lensim/", "docs/", "scripts/", "benchmarks/", "tests/", ".ci/")
# the entry point of every stage, each called in the Python examples
STAGE_CALLS = (
    "load_lens",
    "compute_psf",
    "simulate",
    "make_dataset",
    "train",
    "restore_image",
    "evaluate_methods",
    "run_demo",
)


def python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", TEXT, flags=re.S)


def _shell_snippets() -> list[str]:
    """Every inline code span and every line of the shell blocks."""
    spans = re.findall(r"`([^`\n]+)`", TEXT)
    lines = [ln for block in re.findall(r"```bash\n(.*?)```", TEXT, flags=re.S) for ln in block.splitlines()]
    return spans + lines


def _lensim_commands() -> list[list[str]]:
    """Token lists following each `lensim` (or `.venv/bin/lensim`) in the README's code."""
    found = []
    for snippet in _shell_snippets():
        for part in re.split(r"&&|;|\|", snippet):
            try:
                tokens = shlex.split(part)
            except ValueError:
                continue
            for i, tok in enumerate(tokens):
                if (tok == "lensim" or tok.endswith("/lensim")) and tokens[i - 1 : i] != ["import"]:
                    found.append(tokens[i + 1 :])
    return found


COMMANDS = _lensim_commands()


def _resolve(tokens: list[str]) -> tuple[list[str], Any]:
    """Walk the CLI's command tree along the leading tokens; (path, leaf command)."""
    cmd = typer.main.get_command(app)
    path: list[str] = []
    while hasattr(cmd, "commands"):
        assert tokens[len(path) :], f"`lensim {' '.join(path)}` in README.md is a group, not a command"
        name = tokens[len(path)]
        assert name in cmd.commands, f"README.md shows `lensim {' '.join(path + [name])}`: no such command"
        path.append(name)
        cmd = cmd.commands[name]
    return path, cmd


def test_readme_shows_commands() -> None:
    shown = {" ".join(_resolve(tokens)[0]) for tokens in COMMANDS}
    assert {"demo", "lens info", "psf bank", "dataset make", "train", "restore", "evaluate", "ablation"} <= shown


@pytest.mark.parametrize("tokens", COMMANDS, ids=[" ".join(t) for t in COMMANDS])
def test_every_command_shown_exists_with_its_options(tokens: list[str]) -> None:
    path, cmd = _resolve(tokens)
    opts = {o for p in cmd.params for o in p.opts + p.secondary_opts}
    shown = {t.strip("[]").split("=")[0] for t in tokens[len(path) :] if t.strip("[]").startswith("-")}
    assert shown <= opts, f"`lensim {' '.join(path)}` has no {sorted(shown - opts)}"


def _resolves(dotted: str) -> bool:
    """Whether ``lensim.a.b.c`` is a module or an attribute of one."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj: Any = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        try:
            for attr in parts[cut:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return False
        return True
    return False


def _spec(name: str) -> Any:
    """importlib's spec of a module name, None when it (or its package) does not exist."""
    try:
        return importlib.util.find_spec(name)
    except ModuleNotFoundError:
        return None


def _table_modules() -> list[str]:
    """The stage table's module column as importable names. A bare name (`spot`) is a
    module of one of the packages named before it in the table, the latest first
    (`lensim.optics.lens_file`, `zemax` -> lensim.optics.zemax); one that is in none of
    them is kept bare, and fails to import."""
    modules: list[str] = []
    packages = ["lensim"]
    for row in re.findall(r"^\|(.*)\|\s*$", TEXT, flags=re.M):
        cells = [c.strip() for c in row.split("|")]
        if len(cells) < 4 or cells[2] == "module" or set(cells[2]) <= {"-", " "}:
            continue
        for name in re.findall(r"`([^`]+)`", cells[2]):
            if "." in name:
                modules.append(name)
                spec = _spec(name)
                packages.insert(0, name if spec and spec.submodule_search_locations else name.rsplit(".", 1)[0])
            else:
                modules.append(next((f"{pkg}.{name}" for pkg in packages if _spec(f"{pkg}.{name}")), name))
    return modules


def test_every_module_in_the_stage_table_imports() -> None:
    modules = _table_modules()
    assert len(modules) >= 20
    for name in modules:
        importlib.import_module(name)


def test_every_lensim_name_in_the_text_resolves() -> None:
    names = set(re.findall(r"\blensim(?:\.[A-Za-z_]\w*)+", TEXT))
    assert {"lensim.load_lens", "lensim.run_demo"} <= names
    missing = sorted(n for n in names if not _resolves(n))
    assert not missing, f"README.md names {missing}, which do not exist"


def test_python_examples_import_what_exists_and_call_every_stage() -> None:
    blocks = python_blocks()
    assert len(blocks) >= 2
    called = set()
    for block in blocks:
        for node in ast.walk(ast.parse(block)):
            if isinstance(node, ast.ImportFrom):
                module = importlib.import_module(node.module or "")
                missing = [a.name for a in node.names if not hasattr(module, a.name)]
                assert not missing, f"from {node.module} import {missing}: no such name"
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    importlib.import_module(alias.name)
            elif isinstance(node, ast.Call):
                func = node.func
                called.add(func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None))
                if isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name) and func.value.id == "lensim":
                    assert _resolves(f"lensim.{func.attr}"), f"lensim.{func.attr}"
    assert set(STAGE_CALLS) <= called, f"no example calls {sorted(set(STAGE_CALLS) - called)}"


def test_every_file_and_link_named_exists() -> None:
    links = [m for m in re.findall(r"\]\(([^)#\s]+)", TEXT) if "://" not in m]
    paths = [
        tok.rstrip(".,") for snippet in _shell_snippets() for tok in snippet.split() if tok.startswith(REPO_FOLDERS)
    ]
    assert "scripts/setup.sh" in paths and links
    missing = sorted({p for p in links + paths if not (REPO / p).exists()})
    assert not missing, f"README.md names {missing}, which are not in the repository"


@pytest.mark.slow
def test_readme_examples_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    images = available_sample_images()[:4]
    crop = lambda img: img[:, :256, :256]  # noqa: E731
    write_image(tmp_path / "photo.png", crop(read_sample_image(images[0].name)))
    (tmp_path / "photos").mkdir()
    for img in images:
        write_image(tmp_path / "photos" / f"{img.name}.png", crop(read_sample_image(img.name)))
    namespace: dict = {}
    for block in python_blocks():
        exec(compile(block, str(README), "exec"), namespace)
    assert (tmp_path / "restored.png").is_file()
    assert math.isfinite(namespace["summary"]["methods"]["model"]["psnr_db"])
    assert (tmp_path / "demo" / "report.html").is_file()
