"""The wire: G-code lines, checksums and resends, Marlin replies, transports."""
