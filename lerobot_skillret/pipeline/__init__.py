"""Pipeline stage: the end-to-end runner (generate -> skills -> retrieval -> policy -> evaluation) and results."""
