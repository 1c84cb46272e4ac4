"""The cell's OPC UA address space (docs/opcua.md lists every node): which nodes there are and what a state
change or a finished cycle writes to them.

Built on a server cellctl.service.opcua configured and runs; everything here is called on that server's
event loop. The structure follows OPC 40100 (Machine Vision) as far as it fits a measuring cell: the cell's
object with a VisionStateMachine, RecipeManagement, ResultManagement (LastResult, its history) and a
ResultReadyEventType event per cycle, emitted by the Server object with SourceNode the cell's object.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from asyncua import Node, Server, ua

from cellctl.service.config import OpcUaConfig
from cellctl.service.outcome import CycleOutcome

NAMESPACE = "urn:cellctl:machinevision"

#: LastResult variables: browse name -> (OPC UA type, CycleOutcome field or a function of it).
_RESULT_FIELDS: dict[str, tuple[ua.VariantType, Callable[[CycleOutcome], Any]]] = {
    "ResultId": (ua.VariantType.String, lambda o: o.result_id),
    "CreationTime": (ua.VariantType.DateTime, lambda o: datetime.fromtimestamp(o.triggered_at, UTC)),
    "Cycle": (ua.VariantType.UInt16, lambda o: o.cycle),
    "RecipeId": (ua.VariantType.UInt16, lambda o: o.recipe),
    "RecipeName": (ua.VariantType.String, lambda o: o.recipe_name),
    "IsPass": (ua.VariantType.Boolean, lambda o: o.passed),
    "ResultState": (ua.VariantType.String, lambda o: result_state(o)),
    "ErrorCode": (ua.VariantType.UInt16, lambda o: o.error_code),
    "ErrorName": (ua.VariantType.String, lambda o: o.error_name),
    "LengthMm": (ua.VariantType.Double, lambda o: o.length_mm),
    "HeelHeightMm": (ua.VariantType.Double, lambda o: o.heel_height_mm),
    "ToeHeightMm": (ua.VariantType.Double, lambda o: o.toe_height_mm),
    "CycleTimeMs": (ua.VariantType.Double, lambda o: o.cycle_time_ms),
    "GluePointCount": (ua.VariantType.UInt32, lambda o: o.glue_points),
    "FailedFeatures": (ua.VariantType.String, lambda o: list(o.failed_features)),
}
#: Fields of ResultReadyEventType (each event also has the base fields Time, Message, Severity, SourceNode).
_EVENT_FIELDS = ("ResultId", "Cycle", "RecipeId", "IsPass", "ResultState", "ErrorCode", "LengthMm",
                 "HeelHeightMm", "ToeHeightMm")  # fmt: skip


def result_state(outcome: CycleOutcome) -> str:
    """Pass, Fail (out of tolerance), Measured (no tolerances checked) or Error."""
    if not outcome.measured:
        return "Error"
    return {True: "Pass", False: "Fail", None: "Measured"}[outcome.in_tolerance]


@dataclass
class CellNodes:
    """The nodes a running server writes to; `build` adds the whole address space to a server."""

    state: Node  #: VisionStateMachine/CurrentState
    active_id: Node
    active_name: Node
    last: dict[str, Node]  #: LastResult's variables by browse name
    history: Node
    count: Node
    events: Any  #: asyncua's event generator of ResultReadyEventType

    @classmethod
    async def build(cls, server: Server, cfg: OpcUaConfig, recipes: list[tuple[int, str]]) -> CellNodes:
        idx = await server.register_namespace(NAMESPACE)
        event_type = await server.create_custom_event_type(
            idx, "ResultReadyEventType", ua.ObjectIds.BaseEventType,
            [(name, _RESULT_FIELDS[name][0]) for name in _EVENT_FIELDS],
        )  # fmt: skip
        system = await server.nodes.objects.add_object(idx, cfg.cell_name)
        machine = await system.add_object(idx, "VisionStateMachine")
        state = await machine.add_variable(idx, "CurrentState", "Preoperational")
        management = await system.add_object(idx, "RecipeManagement")
        active_id = await management.add_variable(idx, "ActiveRecipeId", ua.Variant(0, ua.VariantType.UInt16))
        active_name = await management.add_variable(idx, "ActiveRecipeName", "")
        listing = [f"{number}: {name}" for number, name in recipes]
        await management.add_variable(idx, "Recipes", ua.Variant(listing, ua.VariantType.String))
        results = await system.add_object(idx, "ResultManagement")
        last_result = await results.add_object(idx, "LastResult")
        last: dict[str, Node] = {}
        for name, (kind, _) in _RESULT_FIELDS.items():
            empty: Any = [] if name == "FailedFeatures" else _empty(kind)
            last[name] = await last_result.add_variable(idx, name, ua.Variant(empty, kind))
        history = await results.add_variable(idx, "ResultHistory", ua.Variant([], ua.VariantType.String))
        count = await results.add_variable(idx, "ResultCount", ua.Variant(0, ua.VariantType.UInt32))
        # Events are emitted by the Server object (where an MES subscribes, and the only source asyncua's
        # event history can store) with SourceNode = this cell's object, so they say which cell they are from.
        events = await server.get_event_generator(event_type, ua.ObjectIds.Server)
        events.event.SourceNode = system.nodeid
        events.event.SourceName = cfg.cell_name
        # History reads (HistoryReadRaw / HistoryReadEvents) of the last result and its events, in memory.
        await server.historize_node_data_change(last["ResultId"], period=timedelta(days=7), count=cfg.history)
        await server.historize_node_event(server.nodes.server, period=timedelta(days=7), count=cfg.history)
        return cls(state, active_id, active_name, last, history, count, events)

    async def show_state(self, state: str, recipe: tuple[int, str]) -> None:
        """CurrentState and the active recipe."""
        await self.state.write_value(state)
        number, name = recipe
        await self.active_id.write_value(ua.Variant(number, ua.VariantType.UInt16))
        await self.active_name.write_value(name)

    async def show_result(self, outcome: CycleOutcome, history: Iterable[CycleOutcome]) -> None:
        """A finished cycle: LastResult, ResultHistory (newest first), ResultCount, then one event."""
        for name, (kind, value_of) in _RESULT_FIELDS.items():
            await self.last[name].write_value(ua.Variant(value_of(outcome), kind))
        listing = [json.dumps(_jsonable(o)) for o in history]
        await self.history.write_value(ua.Variant(listing, ua.VariantType.String))
        count = await self.count.read_value()
        await self.count.write_value(ua.Variant(count + 1, ua.VariantType.UInt32))
        event = self.events.event
        for name in _EVENT_FIELDS:
            setattr(event, name, _RESULT_FIELDS[name][1](outcome))
        event.Message = ua.LocalizedText(f"cycle {outcome.cycle}: {result_state(outcome)}")
        event.Severity = 100 if outcome.passed else 500
        await self.events.trigger(datetime.now(UTC))


def _empty(kind: ua.VariantType) -> Any:
    return {
        ua.VariantType.String: "",
        ua.VariantType.Boolean: False,
        ua.VariantType.Double: math.nan,
        ua.VariantType.DateTime: datetime.fromtimestamp(0, UTC),
    }.get(kind, 0)


def _jsonable(outcome: CycleOutcome) -> dict[str, Any]:
    data = asdict(outcome)
    data["result_state"] = result_state(outcome)
    data["is_pass"] = outcome.passed
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in data.items()}
