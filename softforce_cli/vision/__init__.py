"""Vision (paper section V-A): robot and object clouds, contacts, feature matches."""
