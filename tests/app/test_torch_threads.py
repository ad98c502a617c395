"""`panogrf.app.viewer.torch_threads`: torch work moved off the calling thread."""

from __future__ import annotations

import threading

import pytest
import torch

from panogrf.app.viewer.torch_threads import off_main_thread, serial_main_thread


def test_off_main_thread_runs_elsewhere_on_the_given_threads():
    seen = {}

    def add(a, b=0):
        seen["thread"] = threading.current_thread()
        seen["threads"] = torch.get_num_threads()
        return a + b

    assert off_main_thread(2, add, 1, b=2) == 3
    assert seen["thread"] is not threading.current_thread()
    assert not seen["thread"].is_alive()  # its OpenMP pool went with it
    assert seen["threads"] == 2


def test_off_main_thread_raises_the_error_in_the_caller():
    def broken():
        raise ValueError("bad scene")

    with pytest.raises(ValueError, match="bad scene"):
        off_main_thread(1, broken)


def test_serial_main_thread_is_serial_inside_and_gives_the_count_back():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with serial_main_thread() as threads:
            assert threads == 2
            assert torch.get_num_threads() == 1
            assert off_main_thread(threads, torch.get_num_threads) == 2
        assert torch.get_num_threads() == 2
        with pytest.raises(RuntimeError), serial_main_thread():
            raise RuntimeError("the session failed")
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
