"""Queries, one module per aggregate (teams, nights, jobs with their files and stages)."""
