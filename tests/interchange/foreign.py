"""railswitch payloads as another team's newer tools write them: keys in another order, spaces, and a field
railswitch does not know (docs/contracts.md, "Changing the contract"). The TypeScript rewriter beside this
file (rewrite.mjs) does the same on its own."""
from __future__ import annotations

import json

EXTRA = {"unit_serial": "PM-4711"}  # what the trackside unit of the recording added
EXTRA_KINDS = ("motor", "throw", "truth")  # the channels that carried it


def foreign_payload(data: bytes, contract: int | None = None) -> bytes:
    """data (a railswitch payload) with its keys reversed, the extra field last, not compact, and written to
    `contract` when given."""
    payload = json.loads(data)
    if contract is not None:
        payload["contract"] = contract
    return json.dumps({**dict(reversed(payload.items())), **EXTRA}).encode()
