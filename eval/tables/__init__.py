"""Tables 1-3 from runs (`gspi-table`): ``cli`` (the entry: which records, which tables),
``build`` (a sweep's rows -> one table's cells, ranks, paired-bootstrap deltas), ``render``
(Markdown / LaTeX / CSV), ``labels`` (the paper's row names and order)."""
