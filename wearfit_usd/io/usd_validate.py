"""Validate a USD stage with every validator registered in usd-core
(``pxr.UsdValidation``; the pip wheel ships no ``usdchecker`` command)."""
from __future__ import annotations


def validate_stage(path_or_stage) -> list[str]:
    """Run all registered validators; return one message per error or
    warning found (empty list = valid)."""
    from pxr import Usd, UsdValidation
    stage = path_or_stage
    if not isinstance(stage, Usd.Stage):
        stage = Usd.Stage.Open(str(path_or_stage))
    registry = UsdValidation.ValidationRegistry()
    validators = registry.GetOrLoadAllValidators()
    ctx = UsdValidation.ValidationContext(validators)
    out = []
    for err in ctx.Validate(stage):
        if err.HasNoError():
            continue
        sites = []
        for s in err.GetSites():
            try:
                sites.append(str(s.GetPrim().GetPath()) if s.IsPrim() else str(s.GetProperty().GetPath()))
            except Exception:
                pass
        out.append(f"{err.GetName()} [{err.GetType()}] {err.GetMessage()} {' '.join(sites)}".strip())
    return out


def validator_count() -> int:
    from pxr import UsdValidation
    return len(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
