"""Seed reproductions: one module (or package) per system; each returns its tables as data."""
