"""Targets under the sea: what each renderer needs of a target's shape."""
