"""`streamfix train-prior`: the command exists and says how to get torch when it is missing."""
from __future__ import annotations

import subprocess
import sys


def test_train_prior_without_torch_names_the_extra(tmp_path):
    code = (
        "import sys\n"
        "sys.modules['torch'] = None  # as if PyTorch were not installed\n"
        "from streamfix.cli import main\n"
        f"sys.exit(main(['train-prior', '--out', {str(tmp_path)!r}]))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "pip install streamfix[train]" in proc.stderr
    assert not any(tmp_path.iterdir())


def test_train_prior_help_lists_its_options():
    proc = subprocess.run([sys.executable, "-m", "streamfix", "train-prior", "--help"], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0
    for opt in ("--data", "--out", "--epochs", "--seed"):
        assert opt in proc.stdout
