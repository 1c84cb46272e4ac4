"""The OPC UA server, read by asyncua's client as the plant's MES would: browse, last result, one event per cycle.

The server runs in its own thread as in the service; the client runs in the test's own event loop. Waits are
on the subscription's queue (events), never on sleeps.
"""

from __future__ import annotations

import asyncio
import json
import math
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua

from cellctl.service.config import OpcUaConfig
from cellctl.service.opcua import NAMESPACE, OpcUaServer, system_state
from cellctl.service.outcome import CycleOutcome
from firmware_io.registers import StatusBit

HEALTHY = StatusBit.READY | StatusBit.CAMERAS_OK | StatusBit.CALIBRATION_OK


def outcome(cycle: int, *, passed: bool | None = True, error: int = 0) -> CycleOutcome:
    nan = math.nan
    return CycleOutcome(
        result_id=f"cell-7-{1000 + cycle}-{cycle}",
        cycle=cycle,
        triggered_at=1_780_000_000.0 + cycle,
        recipe=3,
        recipe_name="Runner 42",
        error_code=error,
        error_name="NONE" if error == 0 else "NO_SOLE",
        length_mm=nan if error else 271.5,
        heel_height_mm=nan if error else 18.2,
        toe_height_mm=nan if error else 7.9,
        cycle_time_ms=812.0,
        glue_points=0 if error else 350,
        in_tolerance=None if error else passed,
        failed_features=() if passed or error else ("LENGTH",),
    )


class Subscriber:
    """An asyncua subscription handler collecting events in an asyncio queue."""

    def __init__(self) -> None:
        self.events: asyncio.Queue[Any] = asyncio.Queue()

    def event_notification(self, event: Any) -> None:
        self.events.put_nowait(event)


@pytest.fixture()
def server() -> Iterator[OpcUaServer]:
    status = {"bits": HEALTHY}
    running = OpcUaServer(
        OpcUaConfig(enabled=True, endpoint="opc.tcp://127.0.0.1:0/cellctl/", cell_name="cell-7", allow_anonymous=True),
        status=lambda: status["bits"],
        recipes=[(0, "cell default"), (3, "Runner 42")],
        active_recipe=lambda: (3, "Runner 42"),
    )
    running.start()
    yield running
    running.stop()


async def browse_names(node: Any) -> set[str]:
    return {(await child.read_browse_name()).Name for child in await node.get_children()}


async def cell_node(client: Client) -> Any:
    idx = await client.get_namespace_index(NAMESPACE)
    return await client.nodes.objects.get_child(f"{idx}:cell-7"), idx


def test_browse_read_the_last_result_and_one_event_per_cycle(server: OpcUaServer) -> None:
    async def scenario() -> None:
        async with Client(server.endpoint, timeout=10) as client:
            cell, idx = await cell_node(client)
            assert await browse_names(cell) >= {"VisionStateMachine", "RecipeManagement", "ResultManagement"}
            state = await cell.get_child([f"{idx}:VisionStateMachine", f"{idx}:CurrentState"])
            assert await state.read_value() == "Ready"
            active = await cell.get_child([f"{idx}:RecipeManagement", f"{idx}:ActiveRecipeId"])
            assert await active.read_value() == 3
            subscriber = Subscriber()
            subscription = await client.create_subscription(50, subscriber)
            event_type = await client.nodes.root.get_child(
                ["0:Types", "0:EventTypes", "0:BaseEventType", f"{idx}:ResultReadyEventType"]
            )
            await subscription.subscribe_events(client.nodes.server, event_type)
            published = [outcome(1), outcome(2, passed=False), outcome(3, error=30)]
            for item in published:
                server.publish(item)
            events = [await asyncio.wait_for(subscriber.events.get(), 10) for _ in published]
            assert [e.Cycle for e in events] == [1, 2, 3]
            assert [e.ResultState for e in events] == ["Pass", "Fail", "Error"]
            assert [e.IsPass for e in events] == [True, False, False]
            assert events[0].ResultId == "cell-7-1001-1" and events[0].LengthMm == pytest.approx(271.5)
            assert all(e.SourceNode == cell.nodeid and e.SourceName == "cell-7" for e in events)
            last = await cell.get_child([f"{idx}:ResultManagement", f"{idx}:LastResult"])
            values = {(await n.read_browse_name()).Name: await n.read_value() for n in await last.get_children()}
            assert values["Cycle"] == 3 and values["ErrorCode"] == 30 and values["IsPass"] is False
            assert values["RecipeId"] == 3 and values["ResultId"] == "cell-7-1003-3"
            assert math.isnan(values["LengthMm"])
            history = await cell.get_child([f"{idx}:ResultManagement", f"{idx}:ResultHistory"])
            rows = [json.loads(row) for row in await history.read_value()]
            assert [row["cycle"] for row in rows] == [3, 2, 1] and rows[1]["failed_features"] == ["LENGTH"]
            # The in-memory event history answers a HistoryReadEvents like a historian would.
            past = await client.nodes.server.read_event_history(None, None, 10, evtypes=[event_type])
            assert sorted(e.Cycle for e in past) == [1, 2, 3]

    asyncio.run(scenario())


def test_anonymous_access_is_refused_unless_configured(tmp_path: Path) -> None:
    secret = tmp_path / "password"
    secret.write_text("s3cret-line-4\n")
    running = OpcUaServer(
        OpcUaConfig(enabled=True, endpoint="opc.tcp://127.0.0.1:0/cellctl/", username="mes", password_file=secret),
        status=lambda: HEALTHY,
        recipes=[(0, "cell default")],
        active_recipe=lambda: (0, "cell default"),
    )
    running.start()

    async def scenario() -> None:
        with pytest.raises(ua.UaError):
            async with Client(running.endpoint, timeout=10) as client:
                await client.nodes.objects.get_children()
        wrong = Client(running.endpoint, timeout=10)
        wrong.set_user("mes")
        wrong.set_password("guess")
        with pytest.raises(ua.UaError):
            async with wrong:
                pass
        right = Client(running.endpoint, timeout=10)
        right.set_user("mes")
        right.set_password("s3cret-line-4")
        async with right:
            assert "cell" in await browse_names(right.nodes.objects)

    try:
        asyncio.run(scenario())
    finally:
        running.stop()


@pytest.mark.parametrize(
    ("status", "stopping", "state"),
    [
        (HEALTHY, False, "Ready"),
        (StatusBit.BUSY | StatusBit.CAMERAS_OK | StatusBit.CALIBRATION_OK, False, "SingleExecution"),
        (StatusBit.CALIBRATION_OK, False, "Error"),
        (HEALTHY, True, "Halted"),
    ],
)
def test_the_state_machine_follows_the_plc_status(status: StatusBit, stopping: bool, state: str) -> None:
    assert system_state(status, stopping) == state


def test_publishing_never_blocks_the_controller_thread(server: OpcUaServer) -> None:
    done = threading.Event()

    def controller() -> None:
        for cycle in range(1, 51):
            server.publish(outcome(cycle))
        done.set()

    threading.Thread(target=controller).start()
    assert done.wait(5)


def test_a_port_in_use_is_one_clear_error() -> None:
    import socket

    from cellctl.errors import UserError

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        server = OpcUaServer(
            OpcUaConfig(enabled=True, endpoint=f"opc.tcp://127.0.0.1:{port}/cellctl/", allow_anonymous=True),
            status=lambda: HEALTHY,
            recipes=[],
            active_recipe=lambda: (0, ""),
        )
        with pytest.raises(UserError, match=f"cannot serve OPC UA on opc.tcp://127.0.0.1:{port}/cellctl/"):
            server.start()
        server.stop()
