"""tests/conftest.py's thread-count fixtures: each sets torch's thread count for its test or block and puts
the previous count back, also when the block raises; the autouse guard catches a test that does not."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import torch


def _tests_conftest():
    """tests/conftest.py loaded by its path: ``from conftest import`` finds whichever conftest module pytest
    imported last under that name (tests/stability/conftest.py when the whole suite runs)."""
    spec = importlib.util.spec_from_file_location("tests_conftest", Path(__file__).with_name("conftest.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _capped(n: int) -> int:
    """``n`` threads, or the one a pytest-xdist worker allows (tests/conftest.py's ``WORKER_THREADS``)."""
    return min(n, _tests_conftest().WORKER_THREADS or n)


def test_two_torch_threads_sets_two(two_torch_threads):
    assert torch.get_num_threads() == _capped(2)


def test_one_torch_thread_sets_one(one_torch_thread):
    assert torch.get_num_threads() == 1


def test_torch_threads_restores_the_count_after_the_block_even_when_it_raises(torch_threads):
    before = torch.get_num_threads()
    with pytest.raises(RuntimeError, match="inside"):
        with torch_threads(3):
            assert torch.get_num_threads() == _capped(3)
            raise RuntimeError("inside")
    assert torch.get_num_threads() == before


def test_the_guard_fails_a_test_that_leaves_the_count_changed():
    """The autouse guard's check, around a block that leaks a changed count: it fails and puts it back."""
    _thread_count_kept = _tests_conftest()._thread_count_kept

    before = torch.get_num_threads()
    with pytest.raises(pytest.fail.Exception, match=f"left torch's thread count at {before + 1}"):
        with _thread_count_kept():
            torch.set_num_threads(before + 1)               # the leak
    assert torch.get_num_threads() == before
    with _thread_count_kept():                              # a block that restores it passes
        torch.set_num_threads(before + 1)
        torch.set_num_threads(before)
