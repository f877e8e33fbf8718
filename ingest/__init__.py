"""Batch jobs that write into the store (rasters, IPM mosaics, road extraction, network import).

Pure image/geometry steps live here as plain functions so they are tested without a database.
"""
