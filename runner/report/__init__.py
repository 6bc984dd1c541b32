"""The results as a reader meets them: one self-contained HTML page (``page``: ``simrun report``) and the summary
table as text and CSV (``summary_table``: ``simrun show``)."""
