"""The optional parts (kernels/extras.py): `require` names the extra of a module that is not there.

A missing module is faked by name: one that exists nowhere, or one set to None in `sys.modules` (Python's own
way to say "not importable"); the modules that are installed are the real ones. The whole path, a clean venv
with the core alone, is tests/test_core_install.py.
"""
from __future__ import annotations

import platform
import sys

import pytest

from host_tools.cli.main import main
from host_tools.exit_codes import EXIT_USAGE
from kernels.extras import ONLY_ON, MissingExtra, missing, require

NOWHERE = "aspod_no_such_module_36"


def test_installed_modules_pass_and_are_not_imported_by_the_check():
    assert "this" not in sys.modules                          # the standard library's Zen: nothing imports it
    require("plot", "json", "this", what="tracker-day --plot")
    assert missing("json", "numpy", "this") == []
    assert "this" not in sys.modules                          # found, not imported: the check costs a start nothing


def test_a_missing_module_names_the_extra_and_the_pip_line():
    with pytest.raises(MissingExtra) as caught:
        require("campaign", "json", NOWHERE, what="campaign")
    said = str(caught.value)
    assert said == (f"campaign: needs the campaign extra ({NOWHERE} is not installed): "
                    "pip install 'aspod[campaign]'")
    assert isinstance(caught.value, ValueError)              # so `aspod` exits 2 (cli/main.py `_run`)
    assert "\n" not in said


def test_several_missing_modules_are_all_named():
    with pytest.raises(MissingExtra, match=rf"needs the fuzz extra \({NOWHERE}, {NOWHERE}_2 are not installed\)"):
        require("fuzz", NOWHERE, "json", f"{NOWHERE}_2", what="fuzz")


def test_a_module_set_to_none_counts_as_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "json", None)
    assert missing("json") == ["json"]
    with pytest.raises(MissingExtra, match=r"needs the compiled extra \(json is not installed\)"):
        require("compiled", "json", what="the compiled joints (ASPOD_COMPILED=1)")


def test_bad_module_names_are_refused_with_a_reason():
    with pytest.raises(ValueError, match="'numba.core' is not a top-level module name"):
        missing("numba.core")
    with pytest.raises(ValueError, match="name the modules"):
        require("plot", what="log --plot")


def test_atheris_off_its_platforms_says_where_it_has_wheels(monkeypatch):
    monkeypatch.setitem(sys.modules, "atheris", None)
    where, _ = ONLY_ON["atheris"]
    with pytest.raises(MissingExtra) as caught:
        require("fuzz", "atheris", what="fuzz")
    said = str(caught.value)
    if (platform.system(), platform.machine()) == where:
        assert said == "fuzz: needs the fuzz extra (atheris is not installed): pip install 'aspod[fuzz]'"
    else:
        assert "atheris has wheels for Linux x86-64 only" in said and "black-box" in said
    monkeypatch.setattr(platform, "system", lambda: "Darwin")
    monkeypatch.setattr(platform, "machine", lambda: "arm64")
    with pytest.raises(MissingExtra, match=r"fuzz: needs atheris, not installed: atheris has wheels for Linux "
                                           r"x86-64 only.*--url, --target-cmd"):
        require("fuzz", "atheris", what="fuzz")


def test_aspod_exits_2_naming_the_extra_of_a_missing_module(monkeypatch, capsys, tmp_path):
    """Through `aspod`'s own main: matplotlib made missing, `tracker-day --plot` refuses before the day runs."""
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.chdir(tmp_path)
    assert main(["tracker-day", "--plot", "day.png"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "tracker-day --plot: needs the plot extra (matplotlib is not installed): pip install 'aspod[plot]'" in err
    assert not (tmp_path / "day.png").exists()
