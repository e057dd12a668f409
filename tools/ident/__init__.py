"""Identification: fitting plant models to captured logs."""
