//! N-ary exact and approximate time synchronisation (in progress).
