"""A session's warning said once per command, across the worker processes of a batch (``--workers``)."""

import multiprocessing
from concurrent.futures import ProcessPoolExecutor

from nlipscalib.core import said_once


def test_a_key_is_said_by_one_process_of_a_shared_folder_and_counts_as_said_afterwards():
    """Two worker processes each warned once of a session's swapped LED images (`nlips solve FOLDER --workers 2`:
    two WARNING lines for one wiring error). Sharing the parent's folder, exactly one of 4 asks says it."""
    key = "led order\0/lab/session\0[0, 1, 7]"
    with said_once.shared_between_processes() as folder:
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(2, mp_context=ctx, initializer=said_once.share, initargs=(folder,)) as pool:
            answers = list(pool.map(said_once.first_time, [key] * 4))
        assert sorted(answers) == [False, False, False, True]
    assert not said_once.first_time(key)  # said by a worker: not again by the command itself
    assert said_once.first_time(key + " another session")


def test_without_a_shared_folder_each_key_is_said_once_in_this_process():
    key = "reference gain\0/lab/solo\0/lab/solo/reference"
    assert [said_once.first_time(key) for _ in range(3)] == [True, False, False]


def test_a_scope_says_each_key_once_and_a_later_scope_again_without_touching_the_process_wide_memory():
    """A notebook's second solve of a folder (a second scope) says the session's warning again; a scope opened
    inside another (``nlips calibrate``'s solves and dataset build) is part of it; bare calls outside keep theirs."""
    key = "led order\0/lab/notebook\0[0, 1, 7]"
    outside = "led order\0/lab/bare\0[0, 1, 7]"
    assert said_once.first_time(outside)
    for _ in range(2):
        with said_once.scope():
            assert said_once.first_time(key)
            with said_once.scope():  # nested: the same scope
                assert not said_once.first_time(key)
            assert not said_once.first_time(key)
            assert said_once.first_time(outside)  # not said in this scope yet
    assert not said_once.first_time(outside)  # the process-wide memory as it was
    assert said_once.first_time(key)  # never said outside a scope
