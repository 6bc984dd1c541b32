"""simrun.systems.contact: contact of mass-spring models (systems/contact/): colliders as signed distance fields,
penalty and IPC barriers, obstacle meshes and self-contact through ipctk, lagged smoothed Coulomb friction."""
