"""The exact search over a horizon's discrete skeleton: which objects, which hand
(docs/search.md)."""
