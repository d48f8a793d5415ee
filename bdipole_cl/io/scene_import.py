"""Which reader a stage or document needs (I/O): USD stages by ``usd_scene``, MaterialX
documents by ``mtlx_scene``; both need the ``usd`` extra (``pxr``, ``MaterialX``)."""
from __future__ import annotations

from pathlib import Path

from .scene_file import SceneError

USD_SUFFIXES = (".usda", ".usd", ".usdc", ".usdz")
MTLX_SUFFIXES = (".mtlx",)
EXTRA = "pip install bdipole-cl[usd]"


def is_imported(path) -> bool:
    """Whether ``path`` is a USD stage or MaterialX document (by its suffix)."""
    return Path(path).suffix.lower() in USD_SUFFIXES + MTLX_SUFFIXES


def import_materials(path) -> list:
    """[ImportedMaterial] of a stage or document (SceneError: one line)."""
    suffix = Path(path).suffix.lower()
    if not Path(path).is_file():
        raise SceneError(f"{path}: no such stage or document")
    try:
        if suffix in MTLX_SUFFIXES:
            from .mtlx_scene import read_document as read
        elif suffix in USD_SUFFIXES:
            from .usd_scene import read_stage as read
        else:
            raise SceneError(f"{path}: not a USD stage ({', '.join(USD_SUFFIXES)}) or a "
                             f"MaterialX document (.mtlx)")
    except ImportError as exc:
        raise SceneError(f"{path}: reading it needs {exc.name or 'pxr and MaterialX'}: "
                         f"{EXTRA}") from None
    return read(path)


def source_files(path) -> set:
    """The real paths of every file a stage is composed of (its root layer and every layer it
    uses: sublayers, references, payloads), or of a document itself: the inputs a bake's
    records must never replace."""
    files = {str(Path(path).resolve())}
    if Path(path).suffix.lower() in USD_SUFFIXES:
        try:
            from .usd_scene import open_stage
            stage = open_stage(path)
        except Exception:                # the import read it, and said what failed
            return files
        files |= {str(Path(layer.realPath).resolve()) for layer in stage.GetUsedLayers()
                  if layer.realPath}
    return files
