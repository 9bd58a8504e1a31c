"""The `wearfit` command: subcommands, inspect output, exit codes."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.conftest import BVH_DIR, USD_DIR
from wearfit_usd.cli import COMMANDS, main


def test_help_lists_every_subcommand(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert name in out


def test_inspect_usd_json(capsys):
    assert main(["inspect", str(USD_DIR / "ref_male.usda"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["up_axis"] == "Z" and info["skeleton"]["joints"] == 53
    assert info["body"]["points"] == 13380 and info["body"]["skin_weights"]["element_size"] == 6
    assert {m["name"] for m in info["items"]} == {"male_casualsuit01", "shoes01", "fedora01",
                                                  "short02", "eyebrow001"}


def test_inspect_usd_text_yup(capsys):
    assert main(["inspect", str(USD_DIR / "body_female_uncommon_yup.usdc"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "up axis Y" in out and "53 joints" in out


def test_inspect_bvh(capsys):
    assert main(["inspect", str(BVH_DIR / "cmu_07_01_walk.bvh"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == 317 and info["joints"] == 31
    assert abs(info["fps"] - 120) < 0.1


def test_bad_input_exit_codes(tmp_path, capsys):
    assert main(["inspect", str(tmp_path / "missing.usda")]) == 2
    assert "file not found" in capsys.readouterr().err
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 3 Xrotation Yrotation Wrotation\n}\n")
    assert main(["inspect", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.bvh:" in err
    txt = tmp_path / "notes.txt"
    txt.write_text("x")
    assert main(["inspect", str(txt)]) == 2


def test_console_script_runs():
    r = subprocess.run([sys.executable, "-m", "wearfit_usd", "inspect", str(USD_DIR / "ref_female.usda")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "ponytail01" in r.stdout
