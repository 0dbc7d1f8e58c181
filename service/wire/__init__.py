"""What goes over the wire: typed, versioned, size-bounded records and the zenoh bus they travel on.
"""
