"""Seed 004 reproduced: the embedded RUL tracker chain on Lu & Meeker crack-growth data
(docs/systems/embedded-rul.md §5); ``rulkit reproduce embedded-rul``."""
