"""Shared pieces of the daemon integration tests (test_daemon.py,
test_query.py; test_daemon re-exports them for the other suites):

- TestFailure, check: a failed expectation;
- running(factory, *extra, **kw): a context manager that starts one daemon
  (factory(*extra, **kw), e.g. test_daemon.Daemon), yields it, and on the way
  out stops it with SIGTERM and checks that it exited 0 with no sanitizer
  report in its log (only when the body succeeded), then always kills what is
  left, closes its log and removes its directory;
- run_tests(tests, only, factory): the suites' runner loop (a test taking one
  argument gets a fresh default daemon, run under `running`).
"""
import contextlib
import shutil
import signal
import time
import traceback


class TestFailure(Exception):
    pass


def check(cond, msg):
    if not cond:
        raise TestFailure(msg)


def check_clean_exit(d, sig=signal.SIGTERM):
    """Stop d (if it still runs) and check exit code 0 and a log free of sanitizer reports."""
    rc, _ = d.stop(sig)
    check(rc == 0, "daemon exit code %r at the end; log:\n%s" % (rc, d.read_log()))
    log = d.read_log()
    check("ERROR: AddressSanitizer" not in log and "runtime error:" not in log, "sanitizer report:\n%s" % log)


@contextlib.contextmanager
def running(factory, *extra, stop=True, remove=True, **kw):
    """Start factory(*extra, **kw) and yield it. stop=False: the body's own
    checks decide (no exit-code check, e.g. a test that kills it on
    purpose); remove=False: its directory belongs to the caller (a tmpdir
    another daemon reuses, e.g. a state file across a restart)."""
    d = factory(*extra, **kw)
    try:
        yield d
        if stop:
            check_clean_exit(d)
    finally:
        d.kill()
        if remove:
            shutil.rmtree(d.tmp, ignore_errors=True)


def run_tests(tests, only, factory):
    """Run every test whose name contains `only`; returns (passed, failed)."""
    passed = failed = 0
    for fn in tests:
        if only not in fn.__name__:
            continue
        t0 = time.time()
        print("--- %s" % fn.__name__, flush=True)
        try:
            if fn.__code__.co_argcount == 1:
                with running(factory) as d:
                    fn(d)
            else:
                fn()
            passed += 1
            print("ok   %s (%.1f s)" % (fn.__name__, time.time() - t0), flush=True)
        except Exception as e:
            failed += 1
            print("FAIL %s: %s" % (fn.__name__, e), flush=True)
            if not isinstance(e, TestFailure):
                traceback.print_exc()
    return passed, failed
