"""The example chain with its `type` declared as a Literal of its own path (the other form a plug-in may use)."""

from typing import Literal

from pendulum_chain import Chain, ChainParams


class LiteralChainParams(ChainParams):
    type: Literal["literal_chain:LiteralChainParams"] = "literal_chain:LiteralChainParams"


LiteralChainParams.system_class = Chain
