"""The parameters' commands (ParamGet, ParamSet, ParamList, ParamSave), beside the store they read and change
(firmware_py/params.py). Each is answered by one parameter's ParamValue (ParamSave by ParamSaved)."""
from __future__ import annotations

from typing import Callable, Optional

from protocol.messages import MESSAGES as M
from protocol.reasons import Reason
from protocol.schema import Message

from firmware_py.handlers import CommandOwner, handles
from firmware_py.params import ParamStore


class ParamCommands(CommandOwner):
    """The commands of `params`; `in_motion_by(name)` names the joint whose running motion uses parameter `name`
    (`ArmController.in_motion_by`), whose ParamSet is then BUSY."""

    def __init__(self, params: ParamStore, in_motion_by: Callable[[str], Optional[str]]) -> None:
        self.params = params
        self._in_motion_by = in_motion_by

    def _param_value(self, reason: Reason, name: str) -> Message:
        spec = self.params.specs.get(name)
        if spec is None:
            return M["ParamValue"](int(reason), name, 0.0, 0.0, 0.0, 0, len(self.params.order), "", "")
        return M["ParamValue"](int(reason), name, self.params[name], spec.lo, spec.hi,
                               self.params.order.index(name), len(self.params.order), spec.unit, spec.doc)

    @handles("ParamGet")
    def _param_get(self, msg: Message, now: float) -> Message:
        known = msg.name in self.params.specs
        return self._param_value(Reason.OK if known else Reason.UNKNOWN_PARAM, msg.name)

    @handles("ParamSet")
    def _param_set(self, msg: Message, now: float) -> Message:
        if self._in_motion_by(msg.name) is not None:
            return self._param_value(Reason.BUSY, msg.name)
        reason, _detail = self.params.set(msg.name, msg.value)
        return self._param_value(reason, msg.name)

    @handles("ParamList")
    def _param_list(self, msg: Message, now: float) -> Message:
        if msg.index >= len(self.params.order):
            return self._param_value(Reason.OUT_OF_RANGE, "")
        return self._param_value(Reason.OK, self.params.order[msg.index])

    @handles("ParamSave")
    def _param_save(self, msg: Message, now: float) -> Message:
        """The file written, or why not (the OS's reason), to the host: `ParamSaved.detail`."""
        reason, detail = self.params.save()
        text = detail if reason is not Reason.OK else str(self.params.path)
        reply = M["ParamSaved"]
        return reply(int(reason), reply.spec.fields[1].fit(text))
