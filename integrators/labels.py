"""How an integrator's parameters read in its label (``Integrator.label``, the sweep's family labels)."""


def parameter_text(key: str, value) -> str:
    """``key=value`` as a label shows it: a float by %g, a list of names joined by + (``none`` when empty)."""
    if isinstance(value, float):
        return f"{key}={value:g}"
    if isinstance(value, (tuple, list)) and all(isinstance(item, str) for item in value):
        return f"{key}={'+'.join(value) or 'none'}"
    return f"{key}={value}"
