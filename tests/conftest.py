"""Shared fixtures and helpers: where the real IFC samples are, and whether their absence is
allowed; `load_script`, for the tests of `scripts/` (imported as `from conftest import ...`,
as `sample_models` is)."""

import importlib.util
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def ifc_samples_dir() -> Path:
    return Path(os.environ.get("BIMGRAPH_IFC_SAMPLES", ROOT.parent / "shared" / "data" / "ifc"))


@pytest.fixture(scope="session")
def ifc_samples() -> Path:
    """The folder of real IFC models; skipped where absent, but a failure under CI."""
    folder = ifc_samples_dir()
    if not any(folder.glob("*.ifc")):
        msg = f"no IFC samples in {folder} (set BIMGRAPH_IFC_SAMPLES)"
        if os.environ.get("CI") == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    return folder


def sample_models() -> list[str]:
    """Names of the sample models, for parametrising (empty if the folder is absent)."""
    return sorted(p.name for p in ifc_samples_dir().glob("*.ifc"))


def load_script(name: str):
    """`scripts/<name>.py` as a module (scripts are not a package)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
