"""Recordings of a run's traffic: the MCAP file format (`recording`) and every message's JSON
form and schema (`msgjson`)."""
