"""Recording: named columns (mx, my, mz, optional t, ax, ay, az, temp, ...) with units and metadata."""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from .._arrays import first_nonfinite, units_text

UNIX_SECONDS = (1e8, 1e10)  # times in this range are clock times (Unix seconds, 1973 to 2286), not seconds from a start
from .columns import (TO_CELSIUS, axis_of_name, field_unit_of, unit_name, find_accelerometer, find_current,
                      find_magnetometer, find_magnetometer_pair, find_position, find_temperature, find_time,
                      rival_magnetometers, sample_rate, TIME_UNITS, words)

# a time column's start when it is a time of day (its date not in it): "12:00:00", "23:59:54.020000"
_TIME_OF_DAY = re.compile(r"\d{2}:\d{2}:\d{2}(?:\.\d+)?")
_MIDNIGHT = re.compile(r"\d{4}-\d{2}-\d{2}(?:T00:00:00(?:\+00:00)?)?")  # a date column's start (no time in it)
MAG_COLUMNS = ("mx", "my", "mz")
# A recording that carries its attitude and the local field (north, east, down) gives a reference vector
# per reading: the vector fit then determines the full matrix (fluxcal.attitude, fluxcal.calibrate).
# said when a column's commas could be decimal commas or thousands separators and no value tells which
COMMAS_HINT = ("; say what their commas are: --decimal , (decimal commas) or --decimal . (thousands separators); "
               "Python: read_recording(..., decimal=',' or '.')")
ATTITUDE_COLUMNS = ("pitch", "roll", "yaw")
FIELD_NED_COLUMNS = ("igrf_n", "igrf_e", "igrf_d")


@dataclass
class Recording:
    columns: dict  # name -> 1-D float array, all the same length
    units: dict = field(default_factory=dict)  # name -> unit string ("nT", "uT", "Gauss", "counts", ...)
    metadata: dict = field(default_factory=dict)
    source: str = "recording"  # file name for messages
    line_numbers: np.ndarray | None = None  # file line of each row, for messages

    def __post_init__(self):
        self.columns = {k: self._column(k, v) for k, v in self.columns.items()}
        lengths = {len(v) for v in self.columns.values()}
        if len(lengths) > 1:
            raise ValueError(f"{self.source}: columns have different lengths {sorted(lengths)}")
        self.mag_columns = MAG_COLUMNS if all(c in self.columns for c in MAG_COLUMNS) else None
        self._mag_unchecked = True  # the triple taken by name, not yet checked for a second one (mag_names)
        # A biaxial sensor's recording (two field columns, see mag_names): which sensor axes they are ("xy", "xz",
        # "yz"), and what said so ("their names", or "" when nothing did and x,y is taken)
        self._biaxial_axes, self._biaxial_axes_from = None, None

    def _column(self, name, values) -> np.ndarray:
        """One column as floats, or ValueError naming it (a 2-D array wrote a file no reader takes back)."""
        try:
            column = np.asarray(values, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{self.source}: column {name!r} is not numbers ({exc})") from None
        if column.ndim != 1:
            raise ValueError(f"{self.source}: column {name!r} has shape {column.shape}, need one value per row")
        return column

    def __len__(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def select(self, names) -> "Recording":
        """Use `names` (three columns, or one string "mx,my,mz" as --columns takes them) as the magnetometer axes;
        two columns are a biaxial sensor's (which axes: by their names, else x,y — see `take_axes`)."""
        names = tuple(n.strip() for n in names.split(",")) if isinstance(names, str) else tuple(names)
        if len(names) not in (2, 3):
            # with a header, --columns names the magnetometer's among its columns (a newcomer had named every one)
            header = f"; of this file's columns ({', '.join(self.columns)}) name the magnetometer's three (two for a biaxial sensor)" if self.columns else ""
            raise ValueError(f"{self.source}: need three magnetometer columns (or two of a biaxial sensor), got "
                             f"{', '.join(names) or 'none'}{header}")
        if len(set(names)) != len(names):
            raise ValueError(f"{self.source}: magnetometer columns {', '.join(names)} repeat a name; give "
                             f"{'three' if len(names) == 3 else 'two'} different columns")
        missing = [n for n in names if n not in self.columns]
        if missing:
            raise ValueError(f"{self.source}: no column {', '.join(repr(m) for m in missing)}; "
                             f"columns are: {', '.join(self.columns)}")
        # One column is not an axis and the clock: `--columns t,mx,my` on three columns made the x readings the
        # times as well, and diagnose sorted the rows by them.
        clock = find_time(self.columns, self.units, None, names)
        if clock is not None and clock[0] in names:
            count = "three" if len(names) == 3 else "two"
            fix = (f"the file has {count} columns, all of them the magnetometer: name them e.g. "
                   f"{'mx,my,mz' if len(names) == 3 else 'mx,my'}" if len(self.columns) == len(names)
                   else f"choose {count} other columns, or rename the time column")
            raise ValueError(f"{self.source}: column {clock[0]!r} is chosen as a magnetometer axis "
                             f"({', '.join(names)}) and its name makes it the time as well; one column cannot be both: "
                             f"{fix}")
        self._biaxial_axes, self._biaxial_axes_from = None, None
        if len(names) == 2:
            names = self._biaxial(names)
        self.mag_columns, self._mag_unchecked = names, False
        return self

    def _biaxial(self, names: tuple, axes: str | None = None) -> tuple:
        """Record that the magnetometer is the two columns `names`, the sensor axes `axes` by their names (None:
        judged here from the names, fluxcal.io.columns.axis_of_name; x,y taken when they do not say, until
        `take_axes` says otherwise). Returns the names in axis order when their names say the axes."""
        if axes is None:
            found = tuple(axis_of_name(n) for n in names)
            if None not in found and found[0] != found[1]:
                names = tuple(n for _, n in sorted(zip(found, names)))
                axes = "".join("xyz"[a] for a in sorted(found))
        self._biaxial_axes, self._biaxial_axes_from = (axes, "their names") if axes else ("xy", "")
        return tuple(names)

    @property
    def biaxial_axes(self):
        """"xy", "xz" or "yz": the sensor axes of a biaxial sensor's two columns (see `biaxial`); None for three
        axes (or no magnetometer found)."""
        self._found()
        return self._biaxial_axes

    @property
    def biaxial_axes_from(self):
        """What said `biaxial_axes`: "their names", what `take_axes` was told ("--planar xz"), or "" when nothing
        did (x,y taken); None for three axes."""
        self._found()
        return self._biaxial_axes_from

    def _found(self) -> None:
        if self.mag_columns is None:
            try:
                self.mag_names()
            except ValueError:
                pass
        if self.mag_columns is not None and len(self.mag_columns) == 2 and self._biaxial_axes is None:
            self.mag_columns = self._biaxial(self.mag_columns)  # two columns set directly, not by select()

    def biaxial(self) -> bool:
        """Whether the magnetometer is a biaxial sensor's two columns (see mag_names): `biaxial_axes` says which
        sensor axes, and `samples(biaxial=True)` gives them N×2; everything that needs three axes refuses it."""
        return len(self.mag_names()) == 2

    def take_axes(self, axes: str, said_by: str) -> None:
        """A biaxial recording's columns are the sensor axes `axes` ("xy", "xz", "yz"), as `said_by` states
        (e.g. "--planar xz", a calibration's file): taken when the column names do not say, checked when they do
        (ValueError naming both)."""
        names = self.mag_names()
        axes = axes.lower()
        if len(names) != 2:
            raise ValueError(f"{self.source}: {said_by} states a biaxial sensor's axes {axes}, but the magnetometer is "
                             f"three columns ({', '.join(names)})")
        if self.biaxial_axes_from == "their names":
            if set(axes) != set(self.biaxial_axes):
                raise ValueError(f"{self.source}: columns {names[0]}, {names[1]} are the sensor's "
                                 f"{' and '.join(self.biaxial_axes)} axes by their names, and {said_by} says "
                                 f"{' and '.join(axes)}: one of them is wrong — correct the column names (or choose "
                                 "others with --columns), or give what matches them")
            return
        self._biaxial_axes, self._biaxial_axes_from = axes, said_by

    def mag_names(self) -> tuple:
        """The three magnetometer columns: those selected, else mx,my,mz, else the triple recognised by
        name (MagX.., mag_x.., Bx.., x,y,z; see fluxcal.io.columns); else two such columns of a biaxial sensor
        (mx,my; Bx,Bz; mag_1,mag_2 — see `biaxial`). A unit carried by the names (mag_x_uT) is recorded when the
        file states none."""
        if self.mag_columns is None:
            found = find_magnetometer(self.columns, self.source, self.units)
            pair = None if found is not None else self._pair()
            if pair is not None:
                found = self._biaxial(*pair)
            if found is None:
                text = self.metadata.get("text_columns")  # a column of numbers in a form the reader did not take
                # (and what a binary format's reader left out: a vector of another length, strings)
                ignored = "; ".join(filter(None, (self.metadata.get(k)
                                                  for k in ("ignored_variables", "ignored_columns"))))
                if len(self.columns) == 1 and not text and not ignored:
                    raise ValueError(f"{self.source}: one column ({next(iter(self.columns))}): a magnetometer's "
                                     "readings are three field columns (mx,my,mz), or two of a biaxial sensor (mx,my, "
                                     "for calibrate --planar); a single field value per reading (a total-field |F|) "
                                     "cannot be calibrated as a vector")
                raise ValueError(f"{self.source}: no magnetometer columns (looked for mx,my,mz, MagX.., mag_x.., "
                                 f"Bx.., x,y,z; columns are: {', '.join(self.columns)}"
                                 f"{f'; left out as text: {text}' if text else ''}"
                                 f"{f'; left out: {ignored}' if ignored else ''}); choose three with "
                                 "--columns / select() (two of a biaxial sensor, for calibrate --planar)"
                                 + (COMMAS_HINT if text and "no value says" in text else ""))
            self.mag_columns = found
            for n in found:
                if not self.units.get(n) and field_unit_of(n):
                    self.units[n] = field_unit_of(n)
        if self._mag_unchecked and len(self.mag_columns) == 3:
            rivals = rival_magnetometers(self.columns, self.mag_columns, self.units)
            if rivals:  # two compasses (mx.. and MagX..; x,y,z and x.1,y.1,z.1): never one taken without a word
                listed = "; ".join(",".join(t) for t in (self.mag_columns, *rivals))
                raise ValueError(f"{self.source}: several magnetometer column triples ({listed}); choose one with "
                                 f"--columns (e.g. --columns {','.join(rivals[0])}) / select()")
        self._mag_unchecked = False
        return self.mag_columns

    def _pair(self):
        """(names, axes) of a biaxial sensor's two columns (fluxcal.io.columns.find_magnetometer_pair), or None;
        None too when a column the reader left out (text, a variable of another shape) completes them to a triple:
        mx,my read with mz left out as text are not a biaxial sensor (the "no magnetometer columns" error names it)."""
        pair = find_magnetometer_pair(self.columns, self.source, self.units)
        if pair is None:
            return None
        (first, second), axes = pair
        if axes:  # a column named as the missing axis beside them (mx,my,mz_uT; mag_z_bad): a 3-axis sensor misnamed
            missing = next(a for a in "xyz" if a not in axes)
            stems = {re.sub(rf"{a}(?!.*{a})", missing, n, flags=re.IGNORECASE).lower()
                     for n, a in ((first, axes[0]), (second, axes[1]))}
            third = [c for c in self.columns if c not in (first, second) and axis_of_name(c) == "xyz".index(missing)
                     and any(c.lower().startswith(stem) for stem in stems)]
            if third:
                raise ValueError(f"{self.source}: columns {first}, {second} name a magnetometer's {axes[0]} and "
                                 f"{axes[1]} axes, and column {third[0]} its {missing} axis in another form: name the "
                                 f"three alike (e.g. m{axes[0]},m{axes[1]},m{missing}) or choose them with --columns "
                                 "(three of a 3-axis sensor, two of a biaxial one)")
        left_out = [entry.split(" (")[0].strip() for key in ("text_columns", "ignored_variables", "ignored_columns")
                    for entry in str(self.metadata.get(key) or "").split("; ") if entry.strip()]
        if left_out:
            try:
                whole = find_magnetometer(list(self.columns) + left_out, self.source, self.units)
            except ValueError:
                whole = None
            if whole is not None and set(pair[0]) < set(whole):
                return None
        return pair

    def time(self):
        """Time of each reading in seconds (column t, else one recognised by name such as time, TimeUS,
        time_ms, timestamp, converted by its unit; else row / rate when the metadata states a sample rate
        such as `# sample_rate_hz: 50`), or None."""
        hit = self._time_column()
        if hit is not None:
            return self.columns[hit[0]] * hit[1]
        rate = sample_rate(self.metadata)
        return None if rate is None else np.arange(len(self)) / rate[1]

    def time_unit_doubt(self) -> str | None:
        """Words for a time column read as seconds though nothing states its unit and it steps by 100 or more per
        sample (a sample every 100 s or more: a milliseconds counter, `millis()`, read as seconds made a blind
        check's thermal lag 3.5 days and its ageing 1000 times too slow), else None. Unix times are not doubted."""
        hit = self._time_column()
        if hit is None or hit[1] != 1.0 or self.units.get(hit[0]) or set(words(hit[0])) & set(TIME_UNITS):
            return None
        t = np.asarray(self.columns[hit[0]], dtype=float)
        steps = np.diff(t[np.isfinite(t)])
        if steps.size == 0 or self.utc_seconds() is not None:
            return None
        step = float(np.median(steps))
        if not step >= 100.0:
            return None
        span = float(np.ptp(t[np.isfinite(t)]))
        return (f"{hit[0]} states no unit and steps by {step:g} per sample: read as seconds (a sample every "
                f"{step / 60:.3g} min, {span / 86400:.3g} days in all); if it counts milliseconds, say so in the "
                f"header ({hit[0]} [ms])")

    def utc_seconds(self):
        """Each reading's clock time as Unix seconds (UTC), or None when the recording's time is not anchored to a
        date: a time column of dates and times (its start in metadata "<column>_start"), a time of day beside a
        column of dates (Date,Time; Datum;Uhrzeit: see `_date_column`), or one already in Unix seconds (1973 to
        2286)."""
        hit = self._time_column()
        if hit is None:
            return None
        t = self.columns[hit[0]] * hit[1]
        start = str(self.metadata.get(f"{hit[0]}_start", ""))
        if _TIME_OF_DAY.fullmatch(start):  # a time of day: a clock time only with the date column beside it
            date = self._date_column(hit[0])
            if date is None:
                return None
            start = f"{date}T{start}"
        if start[:4].isdigit() and start[4:5] == "-":  # a date (a time of day alone is no clock time to match)
            import pandas as pd

            stamp = pd.Timestamp(start)  # a time without a stated zone is taken as UTC, as the readers take it
            return (stamp if stamp.tzinfo else stamp.tz_localize("UTC")).timestamp() + t
        return t if t.size and UNIX_SECONDS[0] <= np.min(t) and np.max(t) <= UNIX_SECONDS[1] else None

    def _date_column(self, time: str):
        """The date (YYYY-MM-DD) on the first reading of the time-of-day column `time` in the column of dates beside
        it, or None: a column read from date stamps (its start in metadata "<column>_start" at midnight) whose
        values are whole days since that start. The time's seconds since its first reading are unwrapped across
        midnight (fluxcal.io.csv._timestamps), so that date and the time's start are all it needs; two date
        columns that disagree are not guessed."""
        import datetime

        first = np.flatnonzero(np.isfinite(self.columns[time]))
        found = set()
        for name, values in self.columns.items():
            start = str(self.metadata.get(f"{name}_start", ""))
            if first.size == 0 or name == time or not _MIDNIGHT.fullmatch(start):
                continue
            days = values[np.isfinite(values)] / 86400.0
            if days.size and np.all(days == np.round(days)) and np.isfinite(values[first[0]]):
                found.add(datetime.date.fromisoformat(start[:10]) + datetime.timedelta(days=values[first[0]] / 86400))
        return found.pop().isoformat() if len(found) == 1 else None

    def _time_column(self):
        """(column, factor to seconds) of the time, or None (fluxcal.io.columns.find_time)."""
        try:
            sensor = self.mag_names()
        except ValueError:  # no magnetometer (yet): no sensor's own clock to prefer
            sensor = None
        return find_time(self.columns, self.units, self.columns, sensor)

    def temperature(self):
        """Temperature of each reading in °C (column temp, else temperature, temp_C, die_temp, ... in °C, K
        or °F by its unit), or None."""
        hit = find_temperature(self.columns, self.units)
        if hit is None:
            return None
        return TO_CELSIUS[hit[1]](self.columns[hit[0]])

    def current(self):
        """Current drawn near the sensor, in A (column current, else curr, motor_current_mA, BAT's Curr, ...
        in A or mA by its unit), or None."""
        hit = find_current(self.columns, self.units)
        return None if hit is None else self.columns[hit[0]] * hit[1]

    def position(self):
        """(latitude °, longitude °, altitude km, the columns as `find_position` names them) of each reading
        (altitude 0 without an altitude column), or None; ValueError when columns are ambiguous or in other units."""
        hit = find_position(self.columns, self.units)
        if hit is None:
            return None
        alt = self.columns[hit["alt"]] * hit["alt_km"] if hit["alt"] else np.zeros(len(self.columns[hit["lat"]]))
        return self.columns[hit["lat"]], self.columns[hit["lon"]], alt, hit

    def acceleration(self):
        """The accelerometer, N×3 (ax,ay,az, else a triple recognised by name such as AccX, accel_x), or None."""
        names = self.acc_names()
        return None if names is None else np.column_stack([self.columns[n] for n in names])

    def acc_names(self):
        """The three accelerometer columns (ax,ay,az, else a triple recognised by name), or None."""
        if all(c in self.columns for c in ("ax", "ay", "az")):
            return ("ax", "ay", "az")
        return find_accelerometer(self.columns)

    def roles(self) -> dict:
        """Which column plays which part, for reports: {"magnetometer": "MagX,MagY,MagZ", "time": ..., ...}."""
        out = {}
        try:
            out["magnetometer"] = ",".join(self.mag_names())
        except ValueError:
            pass
        else:
            if self.biaxial_axes:  # which axes the two are, and what said so (a guess is said as one)
                axes = ", ".join(self.biaxial_axes)
                out["magnetometer"] += (f" (biaxial: axes {axes} by {self.biaxial_axes_from})" if self.biaxial_axes_from
                                        else f" (biaxial: taken as axes {axes}, the names do not say which; "
                                             "--planar xz or yz states others)")
        hit, rate = self._time_column(), sample_rate(self.metadata)
        if hit:
            made = self.metadata.get(hit[0])  # a reader that made the column says how ("row / Fs (Fs = 50 Hz …)")
            out["time"] = hit[0] + (f" (×{hit[1]:g} → s)" if hit[1] != 1.0 else "") + (f" = {made}" if made else "")
        elif rate:
            out["time"] = f"row / {rate[1]:g} Hz (metadata {rate[0]})"
        hit = find_temperature(self.columns, self.units)
        if hit:
            out["temperature"] = hit[0] + (f" ({hit[1]} → °C)" if hit[1] != "C" else "")
        hit = find_current(self.columns, self.units)
        if hit:
            out["current"] = hit[0] + (f" (×{hit[1]:g} → A)" if hit[1] != 1.0 else "")
        acc = self.acc_names()
        if acc:
            out["accelerometer"] = ",".join(acc)
        return out

    def samples(self, check_finite: bool = True, biaxial: bool = False) -> np.ndarray:
        """The magnetometer readings, N×3. NaN/Inf is an error naming the file line and column. A biaxial
        sensor's recording (two field columns) is a ValueError saying so — everything but the planar calibration
        needs three axes — unless `biaxial` (the caller takes N×2, in the axes `biaxial_axes`)."""
        names = self.mag_names()
        if len(names) == 2 and not biaxial:
            axes = " and ".join(self.biaxial_axes)
            how = f"the sensor's {axes} axes by {self.biaxial_axes_from}" if self.biaxial_axes_from else \
                f"taken as its {axes} axes"
            raise ValueError(f"{self.source}: 2 field columns ({names[0]}, {names[1]}: a biaxial magnetometer's, "
                             f"{how}), and this needs three axes' readings; `fluxcal calibrate --planar` "
                             "calibrates two (Python: fluxcal.calibrate_planar(rec), whose calibration's apply "
                             "takes the recording)")
        arr = np.column_stack([self.columns[n] for n in names])
        bad = first_nonfinite(arr) if check_finite else None
        if bad is not None:
            row, col = bad
            where = self.place(row)
            value = arr[row, col]  # an inf may have been written as a number beyond the double range (1e400)
            what = "nan" if np.isnan(value) else f"{'-' if value < 0 else ''}infinite (inf, or beyond ±1.8e308)"
            raise ValueError(f"{self.source}: {where}, column {names[col]!r} is {what} "
                             f"(non-finite readings cannot be calibrated; remove or repair them — a text table "
                             f"read with --bad-lines skip / bad_lines='skip' leaves such lines out)")
        return arr

    def choose(self, columns=None, units: str | None = None) -> "Recording":
        """Apply the reader options every format shares: `columns` (three names, or "a,b,c") selects the
        magnetometer axes, `units` states their unit when the file does not."""
        units = units_text(units)
        columns, pick = instance_pick(columns, self.source)
        self._one_compass(pick)
        if columns is not None:
            self.select(columns)
        if units:
            stated = {unit_name(self.units[n]) for n in self.mag_names() if self.units.get(n)}
            if stated and stated != {unit_name(units)}:  # the file's own statement wins over a default
                raise ValueError(f"{self.source}: units {units!r} given, but the file states the magnetometer in "
                                 f"{', '.join(sorted(stated))}; leave the units out, or correct the file's header")
            for n in self.mag_names():
                self.units[n] = unit_name(units)
        banner = self.metadata.get("field_unit")  # a logger's '# Units: nT' above its header
        if banner:
            if units and unit_name(units) != unit_name(banner):
                raise ValueError(f"{self.source}: units {units!r} given, but the file's comment says {banner}; "
                                 "leave the units out, or correct the file")
            for n in self.mag_names():
                if not self.units.get(n):
                    self.units[n] = unit_name(banner)
                elif unit_name(self.units[n]) != unit_name(banner):
                    raise ValueError(f"{self.source}: column {n!r} is in {self.units[n]} by the header but in "
                                     f"{banner} by the file's '# units:' comment; correct one of them")
        return self

    def _one_compass(self, pick) -> None:
        """Keep the rows of one compass when an instance column (fluxcal.io.columns.find_instance: mavlogdump's `I`,
        PX4's `device_id`) interleaves several: `pick` (name, value) from --columns NAME=VALUE, else the lowest value,
        said in metadata "instance" and "instances" as fluxcal.io.drone says a flight log's (one fit of two compasses'
        rows is a wrong answer that looks like a poor sensor)."""
        from .columns import find_instance

        if pick is None and "instance" in self.metadata:  # a flight log's reader has picked it
            return
        if pick is not None:
            name, value = pick
            if name not in self.columns:
                raise ValueError(f"{self.source}: --columns {name}={value:g}: no column {name!r}; columns are: "
                                 f"{', '.join(self.columns)}")
            kinds, counts = np.unique(self.columns[name], return_counts=True)
            if value not in kinds:
                raise ValueError(f"{self.source}: --columns {name}={value:g}: column {name!r} holds "
                                 f"{', '.join(f'{k:.15g}' for k in kinds[:10])}, not {value:g}")
        else:
            hit = find_instance(self.columns)
            if hit is None:
                return
            (name, kinds, counts), value = hit, hit[1][0]
        rows = self.columns[name] == value
        self.columns = {k: v[rows] for k, v in self.columns.items()}
        if self.line_numbers is not None:
            self.line_numbers = np.asarray(self.line_numbers)[rows]
        said = [f"{name} = {k:.15g} ({c} rows)" for k, c in zip(kinds, counts)]
        self.metadata["instance"] = f"{name} = {value:.15g} ({int(rows.sum())} rows)"
        if len(kinds) > 1:
            other = next(k for k in kinds if k != value)
            left = ", ".join(f"{name} = {k:.15g}" for k in kinds if k != value)
            self.metadata["instances"] = (f"{len(kinds)} compasses interleaved by column {name!r}: {', '.join(said)}; "
                                          f"took {name} = {value:.15g}, left {left}; choose with --columns "
                                          f"{name}={other:.15g} (Python: columns='{name}={other:.15g}')")

    def reference_field(self):
        """The true field of each reading in the sensor frame, N×3, when the recording carries attitude
        (pitch, roll, yaw) and the local field (igrf_n, igrf_e, igrf_d); None otherwise. The attitude
        convention is metadata "attitude_convention" (default "aerospace", see fluxcal.attitude)."""
        if not all(c in self.columns for c in ATTITUDE_COLUMNS + FIELD_NED_COLUMNS):
            return None
        from ..attitude import reference_vectors

        if not any(self.units.get(c) for c in ATTITUDE_COLUMNS):
            self._degrees_or_radians()
        angle_units = {self.units.get(c) or "deg" for c in ATTITUDE_COLUMNS}
        if not angle_units <= {"deg", "rad"} or len(angle_units) > 1:
            raise ValueError(f"{self.source}: attitude columns pitch, roll, yaw must all be in deg or all in rad "
                             f"(units are {', '.join(sorted(angle_units))})")
        ned = np.column_stack([self.columns[c] for c in FIELD_NED_COLUMNS]) * self._reference_scale()
        pitch, roll, yaw = (self.columns[c] for c in ATTITUDE_COLUMNS)
        for name, values in zip(ATTITUDE_COLUMNS + FIELD_NED_COLUMNS, (pitch, roll, yaw, *ned.T)):
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                row = int(bad[0])
                where = self.place(row)
                raise ValueError(f"{self.source}: {where}, column {name!r} is {values[row]} (non-finite)")
        return reference_vectors(ned, pitch, roll, yaw, degrees=angle_units == {"deg"},
                                 convention=str(self.metadata.get("attitude_convention", "aerospace")))

    def _degrees_or_radians(self) -> None:
        """Attitude columns that state no unit are read in degrees; refuse them when no angle goes past 2π (6.3):
        radians read as degrees turn the reference by 1/57 of the attitude, and a calibration turns the sensor
        through far more than 6° of yaw."""
        largest = max(float(np.nanmax(np.abs(self.columns[c]))) for c in ATTITUDE_COLUMNS)
        if largest <= 2 * np.pi + 0.01:
            raise ValueError(f"{self.source}: attitude columns pitch, roll, yaw state no unit and never pass 2π "
                             f"(the largest is {largest:.4g}): radians? Degrees are taken when none is stated; "
                             "state it in the header (pitch [rad], roll [rad], yaw [rad], or [deg])")

    def reference_units(self) -> str:
        """The unit of `reference_field()`: the magnetometer's when both are field units (the local field is
        converted to it), else the local field's own (readings in counts fitted to a field model in nT: the
        vector fit's matrix carries counts per nT, and the corrected field is in nT)."""
        from ..calibration import TESLA_PER_UNIT

        ned, mag = self._reference_unit(), self.field_units()
        return mag if mag in TESLA_PER_UNIT and ned in TESLA_PER_UNIT else ned

    def _reference_unit(self) -> str:
        from ..calibration import TESLA_PER_UNIT

        units = {unit_name(self.units.get(c, "")) for c in FIELD_NED_COLUMNS}  # one spelling
        mag = self.field_units()
        if len(units) > 1 or (mag in TESLA_PER_UNIT and units.pop() not in set(TESLA_PER_UNIT) | {mag}):
            raise ValueError(f"{self.source}: the field columns {', '.join(FIELD_NED_COLUMNS)} are in "
                             f"{', '.join(sorted({self.units.get(c, '') or 'no stated unit' for c in FIELD_NED_COLUMNS}))}, "
                             f"the magnetometer in {mag}: state one field unit for all three (e.g. igrf_n [nT])")
        return unit_name(self.units.get(FIELD_NED_COLUMNS[0], ""))

    def _reference_scale(self) -> float:
        """The factor that takes the local field columns into `reference_units()`."""
        from ..calibration import TESLA_PER_UNIT

        ned, mag = self._reference_unit(), self.field_units()
        if ned in TESLA_PER_UNIT and mag in TESLA_PER_UNIT:
            return TESLA_PER_UNIT[ned] / TESLA_PER_UNIT[mag]
        return 1.0

    def place(self, row: int) -> str:
        """Where a row is, for a message: its line in the file ("line 14"), else its index ("row 11")."""
        return f"line {self.line_numbers[row]}" if self.line_numbers is not None else f"row {row}"

    def stated_field_norm(self):
        """The field norm a `fluxcal simulate` recording states in its metadata, or None."""
        if "simulated" in self.metadata and "field_norm" in self.metadata:
            return float(self.metadata["field_norm"])
        return None

    def field_norms(self, column: str) -> np.ndarray:
        """Each reading's |field| from `column` (a scalar magnetometer's or an observatory's F logged beside the
        readings), in the magnetometer's unit when both state a field unit (F in nT beside readings in µT: divided
        by 1000; calibrate(rec, field_norm=rec.columns["F"]) takes nT as µT, A 1000× too large); as logged when
        either states none. ValueError for a column that is not there, is a magnetometer axis, or states a unit
        that is not a field's. calibrate, twostep and diagnose take `field_norm="F"` for this."""
        from ..calibration import TESLA_PER_UNIT

        if column not in self.columns:
            raise ValueError(f"field_norm: {self.source} has no column {column!r} (columns: {', '.join(self.columns)})")
        if column in self.mag_names():
            raise ValueError(f"field_norm: column {column!r} of {self.source} is a magnetometer axis; name the column "
                             "of each reading's true |field|")
        values = np.asarray(self.columns[column], dtype=float)
        stated, mine = unit_name(self.units.get(column, "")), self.field_units()
        if stated and stated not in TESLA_PER_UNIT and stated != "counts":
            raise ValueError(f"field_norm: column {column!r} of {self.source} is stated in {self.units[column]}, not "
                             "a field unit")
        if stated in TESLA_PER_UNIT and mine in TESLA_PER_UNIT:
            return values * (TESLA_PER_UNIT[stated] / TESLA_PER_UNIT[mine])
        return values

    def field_units(self) -> str:
        """The unit of the magnetometer columns ("" when the recording does not state it)."""
        # one spelling per unit (µT, uTesla, nanotesla, gauss → uT, nT, G): a calibration compares them by name
        units = {unit_name(self.units.get(n, "")) for n in self.mag_names()}
        if len(units) > 1:
            named = {n: self.units.get(n) or "none" for n in self.mag_names()}
            remedy = (f"; if they share {max(units)}, state it for all (--units {max(units)}, units='{max(units)}')"
                      if "" in units and len(units) == 2 else "; convert them to one unit")
            raise ValueError(f"{self.source}: magnetometer columns have different units {sorted(units)} ("
                             + ", ".join(f"{n}: {u}" for n, u in named.items()) + ")" + remedy)
        return units.pop()


def instance_pick(columns, source: str = "recording"):
    """(the magnetometer columns of `columns` (None when it names none), (NAME, value) of a NAME=VALUE item or
    None): --columns I=1 or MagX,MagY,MagZ,I=1 picks the compass of an interleaved table (Recording._one_compass)."""
    if columns is None:
        return None, None
    items = [c.strip() for c in columns.split(",")] if isinstance(columns, str) else list(columns)
    picks = [c for c in items if isinstance(c, str) and "=" in c]
    if not picks:
        return items, None
    name, _, value = picks[0].partition("=")
    try:
        value = float(value)
    except ValueError:
        raise ValueError(f"{source}: --columns {picks[0]}: the compass's value in column {name.strip()!r} is not a "
                         "number") from None
    if len(picks) > 1:
        raise ValueError(f"{source}: --columns picks two compasses ({', '.join(picks)}); give one NAME=VALUE")
    return [c for c in items if c not in picks] or None, (name.strip(), value)


def recording_from_arrays(variables: dict, source: str, matrix: str | None = None, columns=None) -> Recording:
    """A Recording from named arrays of a file that fluxcal did not write (.mat, .npz, Parquet).

    Rule: the magnetometer is the N×3 variable named `matrix`; else the vectors `columns` names (Bx,By,Bz: the
    CLI's --columns); else three vectors named as a magnetometer's axes (mx,my,mz, x,y,z, Bx,By,Bz, MagX…: see
    fluxcal.io.columns); else the only N×3 variable (MATLAB magcal users keep one such matrix); else,
    without any N×3 variable, two vectors a biaxial sensor's columns are named as (mx,my; Bx,Bz: see
    Recording.mag_names).
    The chosen matrix becomes mx,my,mz; any other N×3 variable V becomes V_x, V_y, V_z; vectors of length N
    are columns under their own names; scalars and strings go to the metadata; anything else is listed in
    metadata["ignored_variables"] so that nothing disappears unmentioned.
    """
    vectors, matrices, metadata, ignored = {}, {}, {}, []
    for name, value in variables.items():
        if isinstance(value, str):
            metadata[name] = value
            continue
        arr = np.asarray(value)
        if arr.dtype.kind not in "biuf":
            ignored.append(f"{name} ({arr.dtype.kind} {arr.shape})")
        elif arr.size == 1 and arr.ndim <= 2 and name not in ("mx", "my", "mz", "x", "y", "z"):
            metadata[name] = arr.item()
        elif arr.ndim == 1 or (arr.ndim == 2 and 1 in arr.shape):
            vectors[name] = arr.astype(float).ravel()
        elif arr.ndim == 2 and arr.shape[1] == 3:
            matrices[name] = arr.astype(float)
        else:
            hint = ", transposed?" if arr.ndim == 2 and arr.shape[0] == 3 else ""
            ignored.append(f"{name} ({'×'.join(map(str, arr.shape))}{hint})")
    def described(value) -> str:  # shape, and the type when it is not real numbers (a string or complex N×3)
        arr = np.asarray(value)
        kind = "" if arr.dtype.kind in "biuf" else f" {arr.dtype}, not real numbers"
        return f"{'×'.join(map(str, arr.shape))}{kind}"

    listing = ", ".join(f"{n} ({described(v)})" for n, v in variables.items() if not isinstance(v, str)) or "none"
    named = [c.strip() for c in columns.split(",")] if isinstance(columns, str) else list(columns or ())
    exact = next((list(names) for names in (MAG_COLUMNS, ("x", "y", "z")) if all(c in vectors for c in names)), None)
    triple = None  # the magnetometer's three vectors, when it is not a matrix
    if matrix is not None:
        if matrix not in matrices:
            raise ValueError(f"{source}: no N×3 variable {matrix!r}; numeric variables are: {listing}")
        chosen = matrix
    elif named and all(c in vectors for c in named):  # (Bx,By,Bz vectors had been refused, even named so)
        chosen, triple = None, named
    elif exact:
        chosen, triple = None, exact
    elif len(matrices) == 1:
        chosen = next(iter(matrices))
    elif not matrices and (triple := find_magnetometer(vectors, source)) is not None:
        chosen = None
    elif not matrices and find_magnetometer_pair(vectors, source) is not None:  # a biaxial sensor's two vectors
        chosen = None
    elif matrices:
        raise ValueError(f"{source}: several N×3 variables ({', '.join(matrices)}); name the magnetometer "
                         "one (--columns NAME, or matrix=NAME)")
    else:
        raise ValueError(f"{source}: no N×3 magnetometer matrix and no mx,my,mz vectors; variables are: {listing}"
                         " (readings go one per row: a 3×N matrix must be transposed)")
    if chosen:
        n_rows = len(matrices[chosen])
    else:  # the magnetometer's vectors, else the biaxial pair
        n_rows = len(vectors[triple[0] if triple is not None else find_magnetometer_pair(vectors, source)[0][0]])
    columns = {}
    for name, arr in matrices.items():
        if len(arr) != n_rows:
            ignored.append(f"{name} ({arr.shape[0]}×3, not {n_rows} rows)")
            continue
        axes = MAG_COLUMNS if name == chosen else tuple(f"{name}_{a}" for a in "xyz")
        columns.update(zip(axes, arr.T))
    for name, arr in vectors.items():
        if len(arr) == n_rows and name not in columns:
            columns[name] = arr
        else:
            ignored.append(f"{name} (length {len(arr)}, not {n_rows})")
    if chosen:
        metadata["magnetometer_variable"] = chosen
    if ignored:
        metadata["ignored_variables"] = "; ".join(ignored)
    return Recording(columns=columns, metadata=metadata, source=source)
