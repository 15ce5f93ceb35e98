"""Protocol names and how to build them: the one lookup `compare` and `simulate` use."""

from __future__ import annotations

from pathlib import Path

from agents.protocols import SCRIPTED, Protocol
from excite.errors import ExciteError

#: The policy file shipped with excite (the default of the `learned` protocol).
SHIPPED_POLICY = Path(__file__).parent / "policies" / "excite_ppo.zip"
PROTOCOL_NAMES = (*SCRIPTED, "greedy", "learned")


class ProtocolError(ExciteError, ValueError):
    """An unknown protocol, or a learned policy that cannot be loaded."""


def make_protocol(name: str, policy_path: str | Path | None = None) -> Protocol:
    """Build protocol ``name``; ``learned`` loads ``policy_path`` or the shipped policy."""
    if name in SCRIPTED:
        return SCRIPTED[name]()
    if name == "greedy":
        from agents.greedy import GreedyPlanner

        return GreedyPlanner()
    if name == "learned":
        path = Path(policy_path) if policy_path else SHIPPED_POLICY
        if not path.exists():
            where = "" if policy_path else " (no policy is shipped; train one with excite train)"
            raise ProtocolError(f"learned policy file not found: {path}{where}")
        from agents.learned import LearnedPolicy

        return LearnedPolicy(path)
    raise ProtocolError(f"unknown protocol {name!r}; choose from {', '.join(PROTOCOL_NAMES)}")


def default_protocols(policy_path: str | Path | None = None) -> list[str]:
    """Every protocol that can run here: the learned one only if a policy is available."""
    names = [*SCRIPTED, "greedy"]
    if policy_path or SHIPPED_POLICY.exists():
        names.append("learned")
    return names
