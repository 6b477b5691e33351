"""An atomic fetch-and-add for numba's CPU kernels, which have none.

Parallel loops take their work from a shared counter with it: on a shared machine one core is often slowed down
for a while, and with a fixed split of the work the other core would wait for it at the end of the loop.
"""

from __future__ import annotations

from typing import Any

from fleetslam._imports import require

types = require("numba", "mapping").types
cgutils = require("numba.core.cgutils", "mapping")
intrinsic = require("numba.extending", "mapping").intrinsic


def _fetch_add(typingctx: Any, counters: Any, index: Any, amount: Any) -> Any:
    if not (
        isinstance(counters, types.Array) and counters.dtype == types.int64 and isinstance(index, types.Integer)
        and isinstance(amount, types.Integer)
    ):  # fmt: skip
        return None
    signature = types.int64(counters, index, amount)

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        array_value, index_value, amount_value = args
        array = context.make_array(sig.args[0])(context, builder, array_value)
        index64 = context.cast(builder, index_value, sig.args[1], types.intp)
        amount64 = context.cast(builder, amount_value, sig.args[2], types.int64)
        pointer = cgutils.get_item_pointer(context, builder, sig.args[0], array, [index64], wraparound=False)
        return builder.atomic_rmw("add", pointer, amount64, "monotonic")

    return signature, codegen


#: ``fetch_add(counters, index, amount)``: ``counters[index] += amount`` atomically (an int64 array), in a numba
#: kernel; returns the value before the addition.
fetch_add: Any = intrinsic(_fetch_add)
