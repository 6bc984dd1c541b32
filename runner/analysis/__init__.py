"""What follows from a results file, for every reader after it: the runs with what their series measure
(``runs``), the tables' rows (``rows``) and the number formats (``units``), amplification matrices and what theory
predicts of a method (``oscillator``), reference solutions (``reference``) and the damping map's cells
(``damping_map``). Figures, findings and the report build on these; nothing here draws or writes."""
