"""Security of a run: certificates (`certs`), who may do what (`roles`), the Zenoh settings of a
secure session (`tls`), and the attack that proves it (`audit`). See docs/DECISIONS.md."""
