//! A dynamically typed IPC value, marshalled through any parsed format.
