"""The dataset's contract: the table of stored variables and the labels a sample carries."""
