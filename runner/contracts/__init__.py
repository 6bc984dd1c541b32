"""simrun.contracts (folder runner/contracts/): the contracts of the library's plug-in points as checks that measure
them, one module per contract (``system``: a mechanical system's; ``probes``: where and how those checks measure).
They sit in the runner, not in the library, because a check may step the system with an integrator and a solver,
and systems/ never imports those. tests/test_systems.py and ``simrun check-system`` run the same checks."""
