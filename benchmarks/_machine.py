"""Machine and date stamp shared by the benchmark scripts."""

import datetime
import os
import platform
import subprocess


def machine_info() -> dict:
    model = platform.processor() or "unknown"
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=False).stdout
        for line in out.splitlines():
            if line.startswith("Model name:"):
                model = line.split(":", 1)[1].strip()
    except OSError:
        pass
    import jax

    return {
        "cpu": model,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "date_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M"),
    }


def machine_line(info: dict) -> str:
    return (f"Machine: {info['cpu']}, {info['cores']} cores; Python {info['python']}, "
            f"jax {info['jax']}. Date: {info['date_utc']} UTC.")
