"""One comparison for the API, meant to run in a child process with a memory limit
(tessera_service.compare_process):

    python -m tessera_tools.compare_child TEST REFERENCE OPTIONS_JSON

OPTIONS_JSON: {"alpha", "method", "flip", "max_pixels"}. Prints one JSON object:
{"report": CompareReport} or {"status": 413|422, "error": "..."}, and exits 0.
"""
from __future__ import annotations

import json
import sys


def _main(argv: list[str]) -> int:
    test, reference, options = argv[0], argv[1], json.loads(argv[2])
    max_pixels = int(options.pop("max_pixels"))

    def answer(value: dict) -> int:
        sys.stdout.write(json.dumps(value) + "\n")
        return 0

    import OpenImageIO as oiio
    from tessera_tools.compare import CompareError, compare_files

    # Sizes from the headers first: an image over the limit is refused without decoding.
    for role, path in (("test", test), ("reference", reference)):
        inp = oiio.ImageInput.open(path)
        if inp is None:
            continue  # unreadable: compare_files names the problem (422)
        spec = inp.spec()
        inp.close()
        if spec.width * spec.height > max_pixels:
            return answer({"status": 413, "error": (
                f"{role} is {spec.width}x{spec.height} = {spec.width * spec.height} pixels, more "
                f"than this server compares ({max_pixels}, TESSERA_COMPARE_MAX_PIXELS)")})
    try:
        comparison = compare_files(test, reference, **options)
    except CompareError as exc:
        return answer({"status": 422, "error": str(exc)})
    except MemoryError:
        return answer({"status": 413, "error": "the images are too large to compare within the "
                                               "comparison's memory limit "
                                               "(TESSERA_COMPARE_MEMORY_BYTES)"})
    return answer({"report": comparison.report.model_dump(mode="json")})


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
