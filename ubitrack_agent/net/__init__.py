"""The network layer: zenoh key expressions, settings, sessions, transport helpers, the
component specification handed to host managers, and the logging set-up every process
shares."""
