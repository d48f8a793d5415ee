"""Every example in README.md and docs/*.md runs, so none can drift from the code.

Each fenced block is one test, run in a folder of its own holding small generated inputs
(``example_inputs``): a ``python`` block is executed; a ``sh`` block's lines are
``bdipole-cl`` commands, each run through the CLI and expected to succeed. A block that must
not run (it installs packages, names a cluster or a studio's config) is marked on the line
before its fence with ``<!-- example: skip (the reason) -->``; any other ``sh`` line is a
failure, so a new example is either run or marked. Blocks in other languages (``toml``,
``text``, none) show files or output and are not run.

Also here: the README's length, the API page against ``bdipole_cl.__all__``, and the docs
build with warnings as errors (when Sphinx is installed: the ``docs`` extra).
"""
import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.apps.demo import make_scene, write_exr

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))
SKIP = re.compile(r"<!--\s*example:\s*skip\s*\((?P<reason>[^)]+)\)\s*-->")
FENCE = re.compile(r"^```(?P<lang>\S*)")        # ```python, ```sh, ```{toctree}, ```
#: the README's most lines: one screen and a little (the issue: at most ~150)
README_MAX_LINES = 150

#: a USD stage with one OpenPBR material whose subsurface colour is a UDIM texture
ASSET_USDA = """#usda 1.0
(
    metersPerUnit = 0.001
)

def Material "skin"
{
    token outputs:mtlx:surface.connect = </skin/surface.outputs:out>

    def Shader "surface"
    {
        uniform token info:id = "ND_open_pbr_surface_surfaceshader"
        float inputs:subsurface_weight = 1
        color3f inputs:subsurface_color.connect = </skin/albedo.outputs:rgb>
        color3f inputs:subsurface_radius = (1.2, 0.6, 0.3)
        token outputs:out
    }

    def Shader "albedo"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @albedo.<UDIM>.exr@
        float3 outputs:rgb
    }
}
"""


@dataclass(frozen=True)
class Example:
    page: Path
    line: int                 # the fence's line, 1-based
    lang: str
    code: str
    skip: str | None          # the marker's reason, or None

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def examples(page: Path) -> list[Example]:
    """The fenced blocks of ``page``, each with its language and skip marker."""
    lines = page.read_text().splitlines()
    found, k = [], 0
    while k < len(lines):
        match = FENCE.match(lines[k])
        if not match:
            k += 1
            continue
        end = next(j for j in range(k + 1, len(lines)) if lines[j].startswith("```"))
        before = next((lines[j] for j in range(k - 1, -1, -1) if lines[j].strip()), "")
        marker = SKIP.search(before)
        found.append(Example(page, k + 1, match["lang"], "\n".join(lines[k + 1:end]) + "\n",
                             marker["reason"] if marker else None))
        k = end + 1
    return found


ALL = [e for page in PAGES for e in examples(page)]
RUNNABLE = [e for e in ALL if e.lang in ("python", "sh")]


def write_png8(path, rgb):
    """An 8-bit PNG (OpenImageIO tags it sRGB), ``rgb`` in 0..1."""
    pixels = np.ascontiguousarray(np.round(rgb * 255), dtype=np.uint8)
    out = oiio.ImageOutput.create(str(path))
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], "uint8")
    assert out is not None and out.open(str(path), spec) and out.write_image(pixels), path
    out.close()


def make_example_inputs(folder: Path):
    """The files the examples name (docs/cli.md lists them): two UDIM tiles of albedo and
    mfp, an 8-bit PNG, an irradiance map, the demo's scene, a USD stage and a user kernel."""
    size = 32
    x = np.linspace(0.0, 1.0, size, dtype=np.float32)[None, :].repeat(size, 0)
    for k, tile in enumerate(("1001", "1002")):
        albedo = np.stack([0.3 + 0.5 * x, 0.2 + 0.4 * x, 0.1 + 0.3 * x], -1) * (1 - 0.1 * k)
        write_exr(folder / f"albedo.{tile}.exr", albedo, ("R", "G", "B"))
        write_exr(folder / f"mfp.{tile}.exr", 0.5 + 1.5 * x.T, ("Y",))
    write_png8(folder / "albedo.png", np.stack([0.8 * x, 0.5 * x.T, 0.3 + 0 * x], -1))
    light = np.zeros((size, size, 3), np.float32)
    light[size // 2 - 1:size // 2 + 1] = 1.0
    write_exr(folder / "irradiance.exr", light, ("R", "G", "B"))
    make_scene(folder, size=size)
    (folder / "asset.usda").write_text(ASSET_USDA)
    kernels = folder / "tools" / "examples"
    kernels.mkdir(parents=True)
    shutil.copy(ROOT / "tools" / "examples" / "memo_hery_tm_12_11.cl", kernels)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("example_inputs")
    make_example_inputs(folder)
    return folder


@pytest.fixture
def in_example_folder(inputs, tmp_path, monkeypatch):
    """A fresh copy of the inputs as the working folder."""
    work = tmp_path / "work"
    shutil.copytree(inputs, work)
    monkeypatch.chdir(work)
    return work


def commands(example: Example) -> list[list[str]]:
    """The ``bdipole-cl`` commands of a sh block (comments and blank lines aside); any other
    line is an example that neither runs nor is marked, a failure."""
    out = []
    for line in example.code.splitlines():
        words = shlex.split(line, comments=True)
        if not words:
            continue
        assert words[0] == "bdipole-cl", (f"{example.id}: '{line}' is not a bdipole-cl command: "
                                          f"mark the block <!-- example: skip (why) -->")
        out.append(words[1:])
    return out


def own_cache_folders(folder: Path, monkeypatch):
    """bdipole_cl's cache folders moved into ``folder``: an example of ``cache --clear`` must
    not clear the test run's (it removed the runtime registration and the probes' verdicts
    that the other test processes and their Dask workers were using)."""
    monkeypatch.setenv("BDIPOLE_CL_CACHE_DIR", str(folder / "cache"))
    (folder / "tmp").mkdir()
    monkeypatch.setenv("TMPDIR", str(folder / "tmp"))
    monkeypatch.setattr("tempfile.tempdir", None)      # gettempdir() reads TMPDIR again


def run_sh_example(example: Example, folder: Path, monkeypatch, capsys):
    argvs = commands(example)
    if any(argv[0] == "cache" for argv in argvs):
        own_cache_folders(folder, monkeypatch)
    for argv in argvs:
        rc = cli_main(argv)
        captured = capsys.readouterr()
        assert rc == 0, (example.id, argv, rc, captured.err[-1500:])


@pytest.mark.parametrize("example", RUNNABLE, ids=[e.id for e in RUNNABLE])
def test_example_runs(example, in_example_folder, monkeypatch, capsys):
    if example.skip:
        pytest.skip(example.skip)
    if example.lang == "python":
        exec(compile(example.code, example.id, "exec"), {"__name__": "__example__"})
        return
    run_sh_example(example, in_example_folder, monkeypatch, capsys)


def test_an_example_clearing_the_cache_clears_a_cache_of_its_own(tmp_path, monkeypatch,
                                                                 capsys):
    """The run's cache folder (here a stand-in with a verdict and a registration) survives
    the examples that clear a cache."""
    run_cache = tmp_path / "run-cache"
    kept = [run_cache / "probes" / "0123456789abcdef0123.json",
            run_cache / "icd-0123456789abcdef" / "bdipole_cl-intel-cpu.icd"]
    for path in kept:
        path.parent.mkdir(parents=True)
        path.write_text("{}")
    monkeypatch.setenv("BDIPOLE_CL_CACHE_DIR", str(run_cache))
    clearing = [e for e in RUNNABLE if e.lang == "sh" and not e.skip
                and any(argv[:2] == ["cache", "--clear"] for argv in commands(e))]
    assert clearing, "no example clears the cache: this test has nothing to check"
    for example in clearing:
        work = tmp_path / example.id.replace("/", "_").replace(":", "_")
        work.mkdir()
        with monkeypatch.context() as inner:
            run_sh_example(example, work, inner, capsys)
    assert all(path.is_file() for path in kept)


def test_the_demos_next_steps_run(in_example_folder, capsys):
    """The three commands the demo prints last run as printed, on files named as they say."""
    from bdipole_cl.apps.demo import NEXT_STEPS
    for command, _ in NEXT_STEPS:
        words = shlex.split(command)
        assert words[0] == "bdipole-cl", command
        rc = cli_main(words[1:])
        assert rc == 0, (command, capsys.readouterr().err[-1500:])
    assert (in_example_folder / "out" / "albedo.1001_sss.preview.png").is_file()


def test_examples_are_found():
    # the runner means nothing if the parser finds no block: the README alone has five
    readme = [e for e in RUNNABLE if e.page.name == "README.md"]
    assert len(readme) >= 5 and all(e.skip is None for e in readme[1:]), readme
    assert sum(e.skip is None for e in RUNNABLE) >= 15, len(RUNNABLE)


def test_the_readme_fits_on_a_screen_or_two():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, len(lines)


def test_the_readme_keeps_the_quickstart():
    text = (ROOT / "README.md").read_text()
    assert "pip install . && bdipole-cl demo" in text
    assert 'pip install -e ".[test]" && python -m pytest' in text


def test_the_api_page_lists_the_public_api():
    import bdipole_cl
    page = (ROOT / "docs" / "api.md").read_text()
    listed = re.findall(r"^   (\w+)$", page, flags=re.M)
    assert sorted(listed) == sorted(n for n in bdipole_cl.__all__ if n != "__version__"), listed
    assert "__version__" in page


def test_readme_and_docs_links_resolve():
    """Every relative link of the README and the pages names a file that exists."""
    for page in PAGES:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text()):
            if "://" in target:
                continue
            assert (page.parent / target).exists(), (page.name, target)


@pytest.mark.slow
def test_the_docs_build_with_warnings_as_errors(tmp_path):
    pytest.importorskip("sphinx")
    pytest.importorskip("myst_parser")
    pytest.importorskip("numpydoc")
    pytest.importorskip("sphinxarg")
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    done = subprocess.run([sys.executable, str(ROOT / "tools" / "build_docs.py"),
                           str(tmp_path / "html")], capture_output=True, text=True, env=env,
                          timeout=300)
    assert done.returncode == 0, (done.stdout + done.stderr)[-3000:]
    assert not done.stderr.strip(), done.stderr[-3000:]          # docutils' own messages too
    for page in ("index", "cli_reference", "api", "model", "safety"):
        assert (tmp_path / "html" / f"{page}.html").is_file(), page
