"""The coroutine driver on an actors Loop."""

from __future__ import annotations

import pytest

from actors.loop import Loop
from supervisor.aio import Cancelled, Future, Task, sleep, stop, wait_for


def run(loop: Loop, task: Task, timeout: float = 5.0):
    task.future.add_done_callback(lambda _: stop(loop))
    loop.call_later(timeout, lambda: stop(loop))
    loop.run()
    return task.future


def test_sequential_code_with_awaits() -> None:
    loop = Loop()
    fut: Future[int] = Future(loop)
    order: list[str] = []

    async def job() -> int:
        order.append("start")
        await sleep(loop, 0.01)
        loop.call_later(0.01, lambda: fut.set_result(7))
        value = await fut
        order.append("got")
        return value + (await wait_for(loop, fut, 1.0))

    assert run(loop, Task(loop, job())).result() == 8
    assert order == ["start", "got"]


def test_wait_for_times_out_and_errors_propagate() -> None:
    loop = Loop()
    never: Future[None] = Future(loop)
    bad: Future[None] = Future(loop)
    bad.set_exception(KeyError("k"))

    async def job() -> bool:
        ok = await wait_for(loop, never, 0.02)
        with pytest.raises(KeyError):
            await bad
        return ok

    assert run(loop, Task(loop, job())).result() is False


def test_cancel_runs_finally_and_fails_the_task() -> None:
    loop = Loop()
    cleaned: list[bool] = []

    async def job() -> None:
        try:
            await Future(loop)
        finally:
            cleaned.append(True)

    task = Task(loop, job())
    loop.call_later(0.01, task.cancel)
    assert isinstance(run(loop, task).exception(), Cancelled)
    assert cleaned == [True]


def test_callbacks_run_on_a_later_turn() -> None:
    loop = Loop()
    fut: Future[int] = Future(loop)
    seen: list[int] = []
    fut.add_done_callback(lambda f: seen.append(f.result()))
    fut.set_result(1)
    assert seen == []  # never inside set_result: no re-entrance
    loop.call_later(0.01, lambda: stop(loop))
    loop.run()
    assert seen == [1]
