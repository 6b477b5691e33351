"""Authenticated fleets: a keystore of certificates and the Zenoh configs (mutual TLS, access control) that use it."""
