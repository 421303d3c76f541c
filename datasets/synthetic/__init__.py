"""Deterministic, headless RGB-D renderer of indoor scenes with people, chairs and monitors."""
