"""Ctrl-C that is never lost, and worker processes that end with their parent.

Python turns SIGINT into a ``KeyboardInterrupt`` raised in whatever Python code runs next.
Inside code called back from C, that exception can be lost: casadi turns it into a solver
status (``NonIpopt_Exception_Thrown``) and goes on, and an exception raised in a ctypes
callback (numba's compiler cache) is printed and ignored. The command then ran on and wrote
its files as if nothing had happened.

:func:`install` (called once by the command line) replaces Python's SIGINT handler with one
that also records the request; :func:`check` raises ``KeyboardInterrupt`` again wherever it
matters (the atomic writers of :mod:`ident.data.files` call it before a file or folder
replaces its target, so an interrupted command leaves nothing, however the first exception
was lost); :class:`deferred` keeps SIGINT as a flag only while C code that swallows
exceptions runs (an IPOPT solve), for the caller to stop it and :func:`check` after.

:func:`die_with_parent` is the initializer of forked worker pools: a worker ends when its
parent process is gone, however the parent died (SIGKILL included), instead of living on
as an orphan. :func:`quiet_worker` does that too, and lets Ctrl-C end a worker at once
and without a traceback (a terminal sends SIGINT to every process of the command; the
parent stops and shuts its pool down).
"""

from __future__ import annotations

import os
import signal
import threading

__all__ = ["install", "requested", "check", "reset", "deferred", "die_with_parent",
           "quiet_worker", "PARENT_POLL_S"]

#: How often a worker looks for its parent [s] (:func:`die_with_parent`).
PARENT_POLL_S = 0.5

_state = {"requested": False}


def _handle_sigint(signum, frame):
    _state["requested"] = True
    raise KeyboardInterrupt


def _on_main_thread():
    return threading.current_thread() is threading.main_thread()


def install():
    """Record every SIGINT of this process (and still raise ``KeyboardInterrupt``).

    Does nothing off the main thread, or where SIGINT has a handler other than Python's
    default (an embedding application's, or ignored).
    """
    if _on_main_thread() and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _handle_sigint)


def requested():
    """True once SIGINT arrived after :func:`install` (or inside :class:`deferred`)."""
    return _state["requested"]


def check():
    """Raise ``KeyboardInterrupt`` if SIGINT arrived (:func:`requested`)."""
    if _state["requested"]:
        raise KeyboardInterrupt


def reset():
    """Forget a recorded SIGINT (for a process that goes on after handling it)."""
    _state["requested"] = False


class deferred:
    """While the block runs, SIGINT only sets the flag (:func:`requested`); nothing raises.

    For C code that swallows exceptions raised in its Python callbacks: the callbacks read
    :func:`requested` and stop the C code, and the caller calls :func:`check` after the
    block. On leaving, the handler that was there before is put back. Off the main thread
    it does nothing (no handler can be installed there).
    """

    def __enter__(self):
        self._previous = None
        if _on_main_thread() and signal.getsignal(signal.SIGINT) in (signal.default_int_handler,
                                                                     _handle_sigint):
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    @staticmethod
    def _handle(signum, frame):
        _state["requested"] = True

    def __exit__(self, *exc):
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
        return False


def _watch_parent(parent_pid):
    import time

    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    os._exit(1)  # the parent is gone: nobody reads this worker's results


def die_with_parent(parent_pid):
    """Initializer of a forked worker: end the worker when process `parent_pid` is gone.

    Parameters
    ----------
    parent_pid : int
        The pool's owner (``os.getpid()`` in the parent, passed as ``initargs``).

    Notes
    -----
    A daemon thread polls the parent's pid every :data:`PARENT_POLL_S` seconds (an orphan
    is re-parented, so its ``getppid()`` changes). Unlike Linux's ``PR_SET_PDEATHSIG`` it
    does not depend on which of the parent's threads started the worker, and it works on
    any POSIX system.
    """
    if os.getppid() != parent_pid:  # the parent died before the worker started
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True,
                     name="die-with-parent").start()


def quiet_worker(parent_pid):
    """Initializer of a forked worker: Ctrl-C ends it at once and quietly, and it ends with
    its parent (:func:`die_with_parent`).

    A terminal sends SIGINT to every process of the command. A worker with Python's handler
    would raise ``KeyboardInterrupt`` and print its traceback (each worker one), or finish
    its task first if the handler were ignored; with the default action it ends at once,
    inside C code too, and its parent, interrupted by the same Ctrl-C, stops the pool.

    Parameters
    ----------
    parent_pid : int
        The pool's owner (``os.getpid()`` in the parent, passed as ``initargs``).
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    die_with_parent(parent_pid)
