"""The results file's format, as every stage shares it: where things are (``layout``), the summary table and the
run's status (``summary``), what one run or one chunk of lanes produced (``run_result``) and the bytes a run takes
(``size``). The stepping code builds these rows, the writer stores them, the reader and the tables read them
(docs/results-format.md)."""
