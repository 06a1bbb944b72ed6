"""cab's Every Eval Ever export (``cab-export eee <sweep>``, docs/export.md)."""
