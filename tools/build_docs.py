"""Build the documentation: ``python tools/build_docs.py [OUTDIR]`` (default docs/_build/html).

Sphinx from a fresh environment (``-E``: every page read, so every warning seen), with
warnings as errors (``-W --keep-going``: every warning is listed, then the build
fails), as CI runs it. Needs the ``docs`` extra: ``pip install -e ".[docs]"``."""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    from sphinx.cmd.build import build_main
    argv = sys.argv[1:] if argv is None else argv
    out = argv[0] if argv else str(ROOT / "docs" / "_build" / "html")
    return build_main(["-E", "-W", "--keep-going", "-q", "-b", "html", str(ROOT / "docs"), out])


if __name__ == "__main__":
    sys.exit(main())
