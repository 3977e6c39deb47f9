"""Where the bundled data lives: the operators' page, the paper's calibration, sample pairs.

The data ships inside the package (``app/_data/static``, ``app/_data/sample_data``; in the
repository these are links to the top-level ``static/`` and ``sample_data/``), so it is found
through :mod:`importlib.resources` the same way in an editable install, from a wheel and in the
container. A wheel carries the page, ``calibration.json`` and a few sample pairs (see
``[tool.setuptools.package-data]`` in ``pyproject.toml``); the repository has all of them.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from app.geometry.calibration import StereoCalibration, paper_calibration

DATA_PACKAGE = "app"
DATA_DIR = "_data"
#: The source checkout (tests and benchmarks); in an installed package this is site-packages'
#: parent and holds nothing of ours: use :func:`data_root` for the bundled data.
REPO_ROOT = Path(__file__).resolve().parents[1]


class MissingDataError(FileNotFoundError):
    """A bundled file or sample pair is not in this installation."""


def data_root() -> Path:
    """The package's data directory (``<site-packages>/app/_data`` or ``<repo>/app/_data``)."""
    root = resources.files(DATA_PACKAGE) / DATA_DIR
    # installed from a wheel or editable: the package is on the file system, not in a zip
    return Path(str(root))


def static_dir() -> Path:
    """The operators' page (``index.html``, ``app.js``, ``style.css``)."""
    return data_root() / "static"


def sample_data_dir() -> Path:
    """The bundled sample data (calibration and stereo pairs with ``truth.json``)."""
    return data_root() / "sample_data"


def default_calibration_path() -> Path | None:
    """The bundled calibration (the paper's rig, Tables 1–2), or None if it is missing."""
    path = sample_data_dir() / "calibration.json"
    return path if path.is_file() else None


def load_default_calibration() -> StereoCalibration:
    """The bundled calibration, or the paper's rig (Tables 1–2) if the file is missing."""
    path = default_calibration_path()
    if path is None:
        return paper_calibration()
    return StereoCalibration.load(path)


def sample_pairs() -> list[str]:
    """Names of the sample stereo pairs in this installation (``pair_1000mm``, ...)."""
    root = sample_data_dir()
    if not root.is_dir():
        return []
    return sorted(
        p.name for p in root.iterdir() if (p / "left.png").is_file() and (p / "right.png").is_file()
    )


def sample_pair(name: str) -> tuple[Path, Path]:
    """``(left.png, right.png)`` of a bundled sample pair; :class:`MissingDataError` if absent."""
    names = sample_pairs()
    if name not in names:
        have = ", ".join(names) or "none"
        raise MissingDataError(f"no sample pair {name!r} in this installation (have: {have})")
    folder = sample_data_dir() / name
    return folder / "left.png", folder / "right.png"
