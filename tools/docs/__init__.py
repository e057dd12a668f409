"""The generators of docs/ pages: each module renders (and with ``--check`` compares) one page or one
generated section of a page from what the project's libraries compute. Only the CLIs and these
modules import them (tests/test_architecture.py)."""
