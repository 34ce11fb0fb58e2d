"""The versions of the libraries that shape a result, as recorded in its provenance and listed by `nlips --version`."""

import subprocess
import sys
from importlib import metadata

from nlipscalib.core import libraries
from nlipscalib.core.libraries import INFER_LIBRARIES, RENDER_LIBRARIES, SOLVE_LIBRARIES, library_versions


def test_versions_are_the_installed_distributions_and_none_where_not_installed():
    found = library_versions([*SOLVE_LIBRARIES, "torch", "no-such-library-nlips"])
    assert list(found) == [*SOLVE_LIBRARIES, "torch", "no-such-library-nlips"]  # in the order asked
    assert found["numpy"] == metadata.version("numpy") and found["scipy"] == metadata.version("scipy")
    assert found["opencv"] == metadata.version("opencv-python-headless")  # any of its distribution names
    assert found["torch"] == metadata.version("torch") and found["no-such-library-nlips"] is None


def test_the_header_read_is_the_version_metadata_parses_for_every_installed_distribution():
    """The Version field is read from METADATA's header block (parsing the whole file cost 1-5 ms per library): it
    must equal what importlib.metadata parses, for every distribution of this environment."""
    seen = 0
    for distribution in metadata.distributions():
        assert libraries._version_header(distribution) == distribution.version, distribution.metadata["Name"]
        seen += 1
    assert seen > 20


def test_reading_versions_imports_none_of_the_libraries():
    """Why metadata: recording what made a result must not import torch or mitsuba (seconds) into `nlips solve`."""
    names = [*SOLVE_LIBRARIES, *RENDER_LIBRARIES, *INFER_LIBRARIES["torch"], *INFER_LIBRARIES["onnx"]]
    code = (
        "import sys; from nlipscalib.core.libraries import library_versions; before = set(sys.modules); "
        f"assert all(library_versions({names!r}).values()); "
        "print(sorted(m for m in ('numpy', 'scipy', 'pyamg', 'cv2', 'torch', 'onnxruntime', 'mitsuba', 'drjit') "
        "if m in set(sys.modules) - before))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"
