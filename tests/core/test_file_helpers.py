"""The shared torch-free file helpers."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

from uss_slam.core.files import file_sha256


def test_file_sha256_matches_hashlib_across_block_boundaries(tmp_path: Path) -> None:
    for size in (0, 1, (1 << 20) - 1, 1 << 20, (1 << 20) * 2 + 17):
        data = (bytes(range(251)) * (size // 251 + 2))[size % 7 : size % 7 + size]
        assert len(data) == size
        path = tmp_path / f"f{size}.bin"
        path.write_bytes(data)
        assert file_sha256(path) == hashlib.sha256(data).hexdigest()


def test_files_module_does_not_import_torch() -> None:
    # uss-demo and slam_eval-side users import it; it must stay light.
    code = "import sys, uss_slam.core.files; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
