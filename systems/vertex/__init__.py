"""simrun.systems.vertex: what every system of vertices shares (mass_spring, fem, the cloth, and contact below them),
one concept per module: the errors of a model (errors.py), the config's value types (fields.py), vertex
selectors (selectors.py), the start state (initial_state.py), the constraints of vertices (constraint_config.py),
damping terms (damping.py), the spring model as data (spring_model.py), the flat grid (grids.py), where files
are found (files.py), model files (model_files.py), and the arguments of the compiled vertex kernels
(kernel_arguments.py)."""
