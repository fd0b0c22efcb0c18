"""`import fuseflow` stays light: heavy libraries load only where they are used."""

import subprocess
import sys


def test_core_import_loads_no_heavy_library():
    code = (
        "import sys, fuseflow\n"
        "heavy = ('torch', 'cv2', 'open3d', 'pycolmap', 'numba', 'rerun', 'ray', 'typer', 'pyrealsense2')\n"
        "print(','.join(m for m in heavy if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "", f"import fuseflow loaded: {out}"
