//! `kneebench-fmu-host`: the process an isolated FMU instance runs in (see
//! `kneebench_harness::isolate`). Started by the master with the pipes it talks over; not meant
//! to be run by hand.

fn main() {
    kneebench_harness::isolate::host_main()
}
