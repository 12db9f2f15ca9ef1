"""Cross-process contracts: the types and tables that more than one process (or package) must agree on."""
