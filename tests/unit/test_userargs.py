"""The shared argument types (balloon_core/userargs.py): what each accepts and refuses, with the one line it says."""

from __future__ import annotations

import argparse

import pytest

from balloon_core import userargs


def refused(fn, text: str) -> str:
    with pytest.raises(argparse.ArgumentTypeError) as exc:
        fn(text)
    return str(exc.value)


def test_only_a_character_device_or_a_name_in_dev_is_a_serial_port(tmp_path):
    assert userargs.serial_path("/dev/null") and userargs.serial_path("/dev/ttyUSB7:57600")  # a device; unplugged
    for path in ("/dev/shm/flight.tlog", "/dev/shm/x.tlog:57600", str(tmp_path / "x.tlog"), "flight.tlog"):
        assert not userargs.serial_path(path) and not userargs.is_link(path), path
    assert userargs.is_link("udpin:0.0.0.0:14550") and userargs.is_link("COM3:57600")


def test_a_name_that_ends_in_a_separator_is_no_file_but_may_be_a_directory(tmp_path):
    assert "names a directory" in refused(userargs.output_path, str(tmp_path / "w.csv") + "/")
    assert userargs.output_dir(str(tmp_path / "new") + "/") == str(tmp_path / "new") + "/"
    assert userargs.output_path(str(tmp_path / "w.csv")) == str(tmp_path / "w.csv")


def test_numbers_of_the_link_and_the_cluster():
    assert userargs.sysid("255") == 255 and userargs.sysid("1") == 1
    for bad in ("0", "256", "-1", "x"):
        assert refused(userargs.sysid, bad)
    assert userargs.count("3") == 3 and "must be >= 1" in refused(userargs.count, "0")
    assert userargs.scheduler_address("tcp://10.0.0.5:8786") == "tcp://10.0.0.5:8786"
    assert userargs.scheduler_address("10.0.0.5:8786") == "10.0.0.5:8786"
    for bad in ("bogus", "tcp://host", "tcp://:8786", "host:99999"):
        assert "HOST:PORT" in refused(userargs.scheduler_address, bad)


def test_a_figure_is_named_by_its_format(tmp_path):
    assert userargs.plot_path(str(tmp_path / "p.png")) and userargs.plot_path(str(tmp_path / "p.PDF"))
    assert ".png" in refused(userargs.plot_path, str(tmp_path / "noext"))
