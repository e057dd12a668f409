"""The wire: G-code lines, checksums and resends, Marlin replies, transports."""
import protocol.urlhandler  # noqa: F401  registers twin:// with pyserial (serial_for_url)
