"""``vulkan``: the Khronos validation layer said nothing while this model was uploaded and drawn."""

from __future__ import annotations

from ..results import CheckResult
from .base import Check, Context


class VulkanCheck(Check):
    name = "vulkan"
    measures = "messages of the Khronos validation layer (with synchronization validation) for this model"
    tolerance = "0 messages"
    reason = ("a message is an API misuse that lavapipe may render through but a real GPU need not "
              "(NOTES-vulkan.md: a wrong layout rendered correctly on lavapipe): any message is a fault")

    def run(self, ctx: Context) -> CheckResult:
        r = self.result()
        msgs = ctx.renderer.ctx.take_messages()
        if not ctx.renderer.ctx.validation:
            r.status = "skip"
            r.messages.append("validation layer disabled")
            return r.finish()
        r.figures = {"messages": len(msgs)}
        r.worst("messages", len(msgs), 0)
        r.messages += [f"{sev}: {text}" for sev, text in msgs[:20]]
        return r.finish()


CHECK = VulkanCheck()
