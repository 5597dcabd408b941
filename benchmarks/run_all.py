"""All benchmarks, one after the other: ``make bench``."""

from benchmarks import bench_accuracy, bench_memory, bench_sim, bench_speed, bench_web

if __name__ == "__main__":
    import sys

    sys.argv = sys.argv[:1]
    print("== simulator ==")
    bench_sim.main()
    print("\n== firmware speed ==")
    bench_speed.main()
    print("\n== estimator accuracy ==")
    bench_accuracy.main()
    print("\n== memory of long flights (balloon-fw, reprocess) ==")
    bench_memory.main([])
    print("\n== browser ground station (balloon-gs web, 5 balloons x 10 Hz, 10 minutes; needs chromium) ==")
    bench_web.main([])
