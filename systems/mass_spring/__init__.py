"""simrun.systems.mass_spring: point masses and springs from a model file or a generator (systems/mass_spring/)."""
