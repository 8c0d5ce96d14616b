//! The CANopen Safety layer (EN 50325-5): SRDO, GFC and the safety objects.
