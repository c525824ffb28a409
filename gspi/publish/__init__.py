"""`make results`: the product's committed scores (the store, :mod:`gspi.publish.store`) into the
docs' result tables (:mod:`gspi.publish.docs`). The one package that knows repository paths of
results; the tables themselves are built by eval.tables (the protocol's builder and renderer)."""
